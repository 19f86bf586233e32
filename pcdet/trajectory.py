"""Trajectory errors (Sturm et al. 2012, the TUM RGB-D benchmark's definitions) and trivial baselines.

Poses are ``T_world_cam`` (4, 4, m), one per frame, estimated and ground truth in the same frame order.
"""
from __future__ import annotations

import numpy as np

from .align import kabsch, transform


def ate_rmse(est: list[np.ndarray], gt: list[np.ndarray]) -> float:
    """Absolute trajectory error (m): RMS distance between the camera positions after the rigid alignment of
    the estimated positions onto the true ones (least squares, no scale). est, gt : equally many (4, 4) poses,
    at least one."""
    if len(est) != len(gt) or len(est) == 0:
        raise ValueError(f"ate_rmse needs equally many estimated and true poses, at least one; got {len(est)} "
                         f"and {len(gt)}")
    P = np.array([T[:3, 3] for T in est])
    Q = np.array([T[:3, 3] for T in gt])
    if len(P) < 3:
        A = np.eye(4)
        A[:3, 3] = (Q - P).mean(axis=0)
    else:
        A = kabsch(P, Q)
    return float(np.sqrt(np.mean(np.sum((transform(A, P) - Q) ** 2, axis=1))))


def rpe(est: list[np.ndarray], gt: list[np.ndarray], delta: int = 1) -> tuple[float, float]:
    """Relative pose error over ``delta`` frames: (RMS translation error m, RMS rotation error deg) of
    ``inv(inv(gt_i) gt_j) inv(est_i) est_j`` for j = i + delta."""
    te, re = [], []
    for i in range(len(est) - delta):
        j = i + delta
        E = np.linalg.inv(np.linalg.inv(gt[i]) @ gt[j]) @ (np.linalg.inv(est[i]) @ est[j])
        te.append(np.linalg.norm(E[:3, 3]))
        re.append(np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1.0, 1.0))))
    if not te:
        return 0.0, 0.0
    return float(np.sqrt(np.mean(np.square(te)))), float(np.sqrt(np.mean(np.square(re))))


def identity_baseline(gt: list[np.ndarray]) -> list[np.ndarray]:
    """The camera never moves: every pose is the first true one."""
    return [gt[0].copy() for _ in gt]


def constant_velocity_baseline(gt: list[np.ndarray]) -> list[np.ndarray]:
    """The first true motion (frame 0 to 1), repeated for every later frame."""
    if len(gt) < 2:
        return [T.copy() for T in gt]
    step = np.linalg.inv(gt[0]) @ gt[1]
    out = [gt[0].copy()]
    for _ in gt[1:]:
        out.append(out[-1] @ step)
    return out
