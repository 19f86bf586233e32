"""FPFH descriptors at keypoints, with neighbours taken from the full (dense) cloud.

``fpfh`` computes what open3d's ``compute_fpfh_feature`` computes, with a compiled kernel (``pcdet/_fpfh.c``) that
finds each point's neighbours on a hashed grid of the support radius (``grid.CellGrid``) and runs on several threads;
where the kernel was not built, or the cloud is too wide for the grid's keys, open3d computes it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ConfigError
from .params import check_positive, param

try:  # the compiled kernel, where the install could build it
    from . import _fpfh
except ImportError:  # pragma: no cover - exercised where no compiler was at hand
    _fpfh = None


@dataclass(frozen=True)
class FeatureConfig:
    """FPFH descriptors and the support of the SHOT local reference frames."""

    radius: float = param(0.025, "m; FPFH support radius")
    max_nn: int = param(100, "most neighbours in an FPFH")
    lrf_radius: float = param(0.0, "m; SHOT local reference frame support (Hough grouping); 0: features.radius")

    def __post_init__(self):
        check_positive(self, "radius", "max_nn")
        if self.lrf_radius < 0:
            raise ConfigError(f"FeatureConfig.lrf_radius must be >= 0, got {self.lrf_radius}")

    @property
    def lrf_support(self) -> float:
        """m; the radius local reference frames use: ``lrf_radius``, or ``radius`` when that is 0."""
        return self.lrf_radius or self.radius


def compiled() -> bool:
    """Whether ``fpfh`` runs the compiled kernel (otherwise open3d's implementation)."""
    from . import grid

    return _fpfh is not None and grid.compiled()


def fpfh(points: np.ndarray, normals: np.ndarray, keypoints: np.ndarray, cfg: FeatureConfig, *, workers: int = 1,
         kernel: bool = True) -> np.ndarray:
    """FPFH (Rusu et al. 2009) of ``points[keypoints]``, as open3d's legacy implementation defines it.

    Parameters
    ----------
    points, normals : (N, 3) float64, metres / unit vectors.
    keypoints : (K,) int64 indices into ``points``, in any order (repeats allowed).
    workers : threads (each point's descriptor depends on nothing else: any number gives the same).
    kernel : False: open3d's implementation even where the compiled kernel is at hand.

    Returns
    -------
    (K, 33) float32 descriptors, computed in double precision. A point's neighbours are the ``cfg.max_nn`` nearest
    within ``cfg.radius``. Where more are in reach and several lie at the last distance kept (to the bit), the
    kernel keeps the lowest indices and open3d those its KD-tree meets first: on the real LINEMOD frames (depth in
    whole millimetres) 0-7 % of the keypoints' descriptors differ so, by up to 1.2 in one bin (each group of 11
    sums to 100). Elsewhere the two agree: to the bit on the test clouds, to float32 rounding where neighbours at
    one distance are summed in another order (``tests/test_features.py``).
    """
    if len(keypoints) == 0:
        return np.zeros((0, 33), np.float32)
    keypoints = np.asarray(keypoints, dtype=np.int64)
    # both return the descriptors of the points in increasing index order, whatever order they are asked in
    order = np.argsort(keypoints, kind="stable")
    uniq, back = np.unique(keypoints[order], return_inverse=True)
    points = np.ascontiguousarray(points, dtype=np.float64)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    feats = _fpfh_grid(points, normals, uniq, cfg, workers) if kernel and compiled() else None
    if feats is None:
        feats = _fpfh_open3d(points, normals, uniq, cfg)
    out = np.empty((len(keypoints), 33), np.float32)
    out[order] = feats[back]
    return out


def _fpfh_open3d(points: np.ndarray, normals: np.ndarray, uniq: np.ndarray, cfg: FeatureConfig) -> np.ndarray:
    """(K, 33) float32 FPFH of ``points[uniq]`` (``uniq`` ascending, no repeats), by open3d."""
    from ._o3d import o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pc.normals = o3d.utility.Vector3dVector(normals)
    # open3d's legacy implementation in double precision: 20 % faster than its tensor one, which works in float32
    f = o3d.pipelines.registration.compute_fpfh_feature(
        pc, o3d.geometry.KDTreeSearchParamHybrid(radius=float(cfg.radius), max_nn=int(cfg.max_nn)), uniq.tolist())
    return np.asarray(f.data, dtype=np.float32).T


def _fpfh_grid(points: np.ndarray, normals: np.ndarray, uniq: np.ndarray, cfg: FeatureConfig, workers: int
               ) -> np.ndarray | None:
    """(K, 33) float32 FPFH of ``points[uniq]`` by the compiled kernel, or None where the grid cannot hold the
    cloud. Three passes, each split over ``workers`` threads: the points within reach of the keypoints, their
    SPFH histograms, and the keypoints' FPFH."""
    from .grid import CellGrid, over_threads

    r = float(cfg.radius)
    g = CellGrid(points, r * (1 + 1e-9))  # a point within r of a query lies in the 27 cells around the query's
    if not g.usable:
        return None
    grid = (g.points, g.order, g.start, g.keys, g.table, g.cell)
    r2, nn = r * r, int(cfg.max_nn)

    def split(fn, items: np.ndarray) -> list:
        return over_threads(fn, items, workers, 2000)

    def reach(which):
        mark = np.zeros(len(points), np.uint8)
        _fpfh.reach(*grid, points, which, r2, nn, mark)
        return mark

    sorted_normals = np.ascontiguousarray(normals[g.order])

    def spfh(which):
        out = np.empty((len(which), 33))
        _fpfh.spfh(*grid, sorted_normals, which, r2, nn, out)
        return out

    need = np.flatnonzero(np.bitwise_or.reduce(split(reach, uniq), axis=0))
    at = np.empty(len(points), np.int64)
    at[g.order] = np.arange(len(points))  # each point's position in the grid's order
    hist = np.concatenate(split(spfh, at[need]))
    row = np.full(len(points), -1, np.int64)
    row[need] = np.arange(len(need))

    def describe(which):
        out = np.empty((len(which), 33))
        _fpfh.fpfh(*grid, points, which, r2, nn, hist, row, out)
        return out

    return np.concatenate(split(describe, uniq)).astype(np.float32)
