"""Local reference frames at keypoints: the SHOT frame (Tombari, Salti, Di Stefano 2010) with its sign
disambiguation, the rotation-invariant basis that 6-DoF Hough voting attaches votes to.

At keypoint p with neighbours q_i within radius R, the frame's axes are the eigenvectors of the distance-
weighted covariance M = sum (R - d_i)(q_i - p)(q_i - p)^T / sum (R - d_i), d_i = |q_i - p|: x the largest,
z the smallest (the normal direction), y = z x x. Each of x and z is turned to point where most neighbours
lie (the sign with more positive than negative projections (q_i - p) . axis; where as many lie on each side, the
sign of sum w_i (q_i - p) . axis), which makes the frame repeatable: the rule gives the same axis whichever sign the
eigen-solver returned (a zero projection, such as the keypoint's own, counts on neither side).

A small compiled kernel (``pcdet/_lrf.c``, built by ``setup.py`` where a C compiler is at hand) finds the neighbours
on a hashed grid of the radius (``grid.CellGrid``) and the axes by Jacobi's method, on several threads; otherwise,
or where the cloud is too wide for the grid's keys, a KD-tree and numpy's ``eigh``. The two round differently (the
frames' entries agree within about 1e-12 where the eigenvalues are well apart; where two are nearly equal the axes
between them are ill-defined and either may be taken; ``tests/test_lrf.py``); the KD-tree also counts points at
exactly the radius, which weigh nothing.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

try:  # the compiled kernel, where the install could build it
    from . import _lrf
except ImportError:  # pragma: no cover - exercised where no compiler was at hand
    _lrf = None


def compiled() -> bool:
    """Whether ``shot_lrf`` runs the compiled kernel (otherwise a KD-tree and numpy)."""
    from . import grid

    return _lrf is not None and grid.compiled()


def shot_lrf(points: np.ndarray, keypoints: np.ndarray, radius: float, tree: cKDTree | None = None,
             min_neighbours: int = 8, *, workers: int = 1, kernel: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """SHOT local reference frames.

    Parameters
    ----------
    points : (N, 3) cloud (m); keypoints : (K, 3) positions (m) to describe; radius : support radius (m).
    tree : a KD-tree of ``points``, for the numpy path (built when needed).
    workers : threads (each keypoint's frame is the same for any number).
    kernel : False takes the KD-tree and numpy even where the compiled kernel is built (the tests compare the two).

    Returns
    -------
    frames : (K, 3, 3) float64, rows x, y, z of each frame (a proper rotation: ``frames[k] @ v`` expresses a
        world vector v in keypoint k's frame); all NaN where the frame is not valid.
    valid : (K,) bool, False where fewer than ``min_neighbours`` points support the frame.
    """
    K = len(keypoints)
    if kernel and compiled() and K and 0 < radius < np.inf:
        frames = _lrf_grid(points, keypoints, radius, min_neighbours, workers)
        if frames is not None:
            return frames, ~np.isnan(frames[:, 0, 0])
    tree = tree if tree is not None else cKDTree(points)
    frames = np.tile(np.eye(3), (K, 1, 1))
    if K == 0:
        return frames, np.zeros(0, bool)
    nb = tree.query_ball_point(keypoints, radius, workers=workers)
    counts = np.array([len(n) for n in nb])
    owner = np.repeat(np.arange(K), counts)
    idx = np.concatenate([np.asarray(n, np.int64) for n in nb]) if counts.sum() else np.zeros(0, np.int64)
    diff = points[idx] - keypoints[owner]
    w = radius - np.sqrt(np.einsum("ij,ij->i", diff, diff))
    M = np.zeros((K, 3, 3))
    for a in range(3):  # the weighted covariance, one bincount per entry of its upper triangle
        for b in range(a, 3):
            M[:, a, b] = M[:, b, a] = np.bincount(owner, weights=(diff[:, a] * diff[:, b]) * w, minlength=K)
    wsum = np.bincount(owner, weights=w, minlength=K)
    valid = (counts >= min_neighbours) & (wsum > 0)
    M[valid] /= wsum[valid, None, None]
    _, vec = np.linalg.eigh(M[valid])  # ascending eigenvalues; columns are eigenvectors
    x = vec[:, :, 2]
    z = vec[:, :, 0]
    vi = np.flatnonzero(valid)
    pos = np.full(K, -1)
    pos[vi] = np.arange(len(vi))
    sel = valid[owner]
    o, d, ws = (pos[owner], diff, w) if sel.all() else (pos[owner[sel]], diff[sel], w[sel])
    for axis in (x, z):
        proj = np.einsum("ij,ij->i", d, axis[o])
        lead = np.bincount(o, weights=np.sign(proj), minlength=len(vi))  # (positive) - (negative)
        tie = lead == 0  # as many on each side: the side the weighted offsets lean to
        if tie.any():
            lead[tie] = np.bincount(o, weights=proj * ws, minlength=len(vi))[tie]
        axis[lead < 0] *= -1
    y = np.cross(z, x)
    frames[valid] = np.stack([x, y, z], axis=1)
    frames[~valid] = np.nan
    return frames, valid


def _lrf_grid(points: np.ndarray, keypoints: np.ndarray, radius: float, min_neighbours: int, workers: int
              ) -> np.ndarray | None:
    """(K, 3, 3) frames by the compiled kernel (NaN where not valid), or None where the grid cannot hold the cloud."""
    from .grid import CellGrid, over_ranges

    g = CellGrid(np.asarray(points, np.float64), radius * (1 + 1e-9))  # a point within reach lies in the 27 cells
    if not g.usable:
        return None
    q = np.ascontiguousarray(keypoints, dtype=np.float64)
    out = np.empty((len(q), 9))

    def run(lo: int, hi: int) -> None:  # a contiguous run of queries
        _lrf.frames(g.points, g.order, g.start, g.keys, g.table, g.cell, q[lo:hi], float(radius),
                    int(min_neighbours), out[lo:hi])

    over_ranges(run, len(q), workers, 2000)
    return out.reshape(-1, 3, 3)
