"""Local reference frames at keypoints: the SHOT frame (Tombari, Salti, Di Stefano 2010) with its sign
disambiguation, the rotation-invariant basis that 6-DoF Hough voting attaches votes to.

At keypoint p with neighbours q_i within radius R, the frame's axes are the eigenvectors of the distance-
weighted covariance M = sum (R - d_i)(q_i - p)(q_i - p)^T / sum (R - d_i), d_i = |q_i - p|: x the largest,
z the smallest (the normal direction), y = z x x. Each of x and z is turned to point where most neighbours
lie (the sign with more non-negative projections (q_i - p) . axis), which makes the frame repeatable.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def shot_lrf(points: np.ndarray, keypoints: np.ndarray, radius: float, tree: cKDTree | None = None,
             min_neighbours: int = 8, *, workers: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """SHOT local reference frames.

    Parameters
    ----------
    points : (N, 3) cloud (m); keypoints : (K, 3) positions (m) to describe; radius : support radius (m).
    workers : threads of the neighbour search (each keypoint's neighbours are the same for any number).

    Returns
    -------
    frames : (K, 3, 3) float64, rows x, y, z of each frame (a proper rotation: ``frames[k] @ v`` expresses a
        world vector v in keypoint k's frame); all NaN where the frame is not valid.
    valid : (K,) bool, False where fewer than ``min_neighbours`` points support the frame.
    """
    tree = tree if tree is not None else cKDTree(points)
    K = len(keypoints)
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
    o, d = (pos[owner], diff) if sel.all() else (pos[owner[sel]], diff[sel])
    for axis in (x, z):
        proj = np.einsum("ij,ij->i", d, axis[o])
        lead = np.bincount(o, weights=np.where(proj >= 0, 1.0, -1.0), minlength=len(vi))  # (non-negative) - (negative)
        axis[lead < 0] *= -1
    y = np.cross(z, x)
    frames[valid] = np.stack([x, y, z], axis=1)
    frames[~valid] = np.nan
    return frames, valid
