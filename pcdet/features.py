"""FPFH descriptors at keypoints, with neighbours taken from the full (dense) cloud."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ConfigError
from .params import check_positive, param


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


def fpfh(points: np.ndarray, normals: np.ndarray, keypoints: np.ndarray, cfg: FeatureConfig) -> np.ndarray:
    """FPFH (Rusu et al. 2009) of ``points[keypoints]``.

    Parameters
    ----------
    points, normals : (N, 3) float64, metres / unit vectors.
    keypoints : (K,) int64 indices into ``points``, in any order (repeats allowed).

    Returns
    -------
    (K, 33) float32 descriptors (open3d's legacy implementation, in double precision: deterministic, per-point
    independent).
    """
    from ._o3d import o3d

    if len(keypoints) == 0:
        return np.zeros((0, 33), np.float32)
    keypoints = np.asarray(keypoints, dtype=np.int64)
    # open3d returns the descriptors of the points in increasing index order, whatever order they are asked in
    order = np.argsort(keypoints, kind="stable")
    uniq, back = np.unique(keypoints[order], return_inverse=True)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    pc.normals = o3d.utility.Vector3dVector(np.asarray(normals, dtype=np.float64))
    # open3d's legacy implementation in double precision: 20 % faster than its tensor one, which works in float32
    f = o3d.pipelines.registration.compute_fpfh_feature(
        pc, o3d.geometry.KDTreeSearchParamHybrid(radius=float(cfg.radius), max_nn=int(cfg.max_nn)), uniq.tolist())
    feats = np.asarray(f.data, dtype=np.float32).T
    out = np.empty((len(keypoints), 33), np.float32)
    out[order] = feats[back]
    return out
