"""ICP refinement: point-to-plane with a Tukey robust kernel, deterministic (no threaded reductions)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .align import transform
from .errors import ConfigError
from .params import check_positive, param


# m; the least residual spread ``scale_fit`` assumes (a Kinect's depth noise at close range): on noise-free data
# a scale the view does not fix would otherwise look certain
NOISE_FLOOR = 0.001


@dataclass(frozen=True)
class RefineConfig:
    """ICP refinement of hypotheses."""

    iterations: int = param(30, "ICP iterations at most")
    max_distance: float = param(0.012, "m; ICP correspondence distance")
    kernel: float = param(0.006, "m; Tukey kernel width of the point-to-plane residual")
    max_per_model: int = param(3, "hypotheses per model refined fully by ICP (best after the coarse look first, "
                                  "on distinct spots of the scene first, as many as instances are wanted)")
    candidates: int = param(12, "raw hypotheses per model (best first look first, distinct spots first) given a "
                                "short coarse ICP, after which the best max_per_model are refined fully (0: no "
                                "coarse stage)")
    coarse_distance: float = param(0.03, "m; correspondence distance of the coarse ICP (then two thirds of it): "
                                         "raw poses 1-3 cm off come within the full ICP's reach")
    coarse_points: int = param(300, "model samples the coarse ICP moves (evenly taken from the ICP samples)")

    def __post_init__(self):
        check_positive(self, "iterations", "max_distance", "kernel", "max_per_model", "coarse_distance",
                       "coarse_points")
        if self.candidates < 0:
            raise ConfigError(f"RefineConfig.candidates must be >= 0, got {self.candidates}")


@dataclass
class RegistrationResult:
    """``T_target_source`` (4, 4) and how well it fits: ``fitness`` is the share of source points with a
    target point within ``max_distance``, ``rmse_m`` the RMS point-to-plane residual of those points."""

    T_target_source: np.ndarray
    fitness: float
    rmse_m: float
    n_inliers: int
    iterations: int
    converged: bool


def icp(source: np.ndarray, target: np.ndarray, target_normals: np.ndarray, T_init: np.ndarray,
        cfg: RefineConfig, *, source_normals: np.ndarray | None = None, target_tree: cKDTree | None = None,
        viewpoint: np.ndarray | None = None, tolerance: tuple[float, float] = (1e-5, 1e-6),
        weights: np.ndarray | None = None) -> RegistrationResult:
    """Point-to-plane ICP of ``source`` (N, 3) onto ``target`` (M, 3) with ``target_normals`` (M, 3).

    ``weights`` : optional (N,) non-negative weight of each source point, multiplying the robust kernel's (for
    instance the inverse of its measurement noise variance).

    It stops after ``cfg.iterations`` or once a step turns less than ``tolerance[0]`` (rad) and moves less than
    ``tolerance[1]`` (m).

    With ``source_normals`` and a ``viewpoint`` (target frame, e.g. the camera origin), only source points whose
    normals face the viewpoint take part, as only they can have been seen.
    """
    if weights is not None and np.shape(weights) != (len(source),):
        raise ValueError(f"icp weights must be one per source point ({len(source)},), got {np.shape(weights)}")
    tree = target_tree if target_tree is not None else cKDTree(target)
    T = np.asarray(T_init, float).copy()
    converged = False
    it = 0
    for it in range(1, cfg.iterations + 1):
        p, q, n, w, _ = _pairs(source, source_normals, target, target_normals, tree, T, cfg=cfg, viewpoint=viewpoint,
                              weights=weights)
        if len(p) < 6:
            break
        r = ((p - q) * n).sum(axis=1)
        J = _jacobian(p, n)
        Jw = J.T * w
        try:
            x = np.linalg.solve(Jw @ J + 1e-9 * np.eye(6), -(Jw @ r))
        except np.linalg.LinAlgError:
            break
        T = _motion(x) @ T
        if np.linalg.norm(x[:3]) < tolerance[0] and np.linalg.norm(x[3:]) < tolerance[1]:
            converged = True
            break
    p, q, n, w, n_src = _pairs(source, source_normals, target, target_normals, tree, T, cfg=cfg, viewpoint=viewpoint)
    r = ((p - q) * n).sum(axis=1)
    rmse = float(np.sqrt((r ** 2).mean())) if len(r) else float("inf")
    return RegistrationResult(T, len(p) / max(n_src, 1), rmse, len(p), it, converged)


def scale_fit(source: np.ndarray, target: np.ndarray, target_normals: np.ndarray, T_init: np.ndarray,
              cfg: RefineConfig, *, source_normals: np.ndarray, target_tree: cKDTree,
              viewpoint: np.ndarray) -> tuple[float, float]:
    """The size that fits: point-to-plane ICP of ``source`` (N, 3, with ``source_normals``) onto ``target`` (M, 3,
    with ``target_normals``) from ``T_init`` (4, 4) as in ``icp``, with a scale about the source's centroid free
    besides the pose. Returns ``(s, sd)``: the scale (1: the source's own size fits best) and its standard
    deviation from the last Gauss-Newton step's normal matrix (inf where the view does not fix the size, as when
    only three faces of a box are seen: scaling about the centre and moving the corner then look the same).
    ``s`` is 1 and ``sd`` inf when fewer than 7 source points find a target point; ``sd`` is inf as well when the
    scale runs out of [0.5, 2]. The residual spread behind ``sd`` is at least ``NOISE_FLOOR``."""
    tree, T = target_tree, np.asarray(T_init, float).copy()
    c0 = source.mean(axis=0)
    s, last = 1.0, None
    for _ in range(cfg.iterations):
        p, q, n, w, _ = _pairs(c0 + s * (source - c0), source_normals, target, target_normals, tree, T, cfg=cfg,
                               viewpoint=viewpoint)
        if len(p) < 7 or w.sum() <= 0:
            return 1.0, float("inf")
        r = ((p - q) * n).sum(axis=1)
        J = np.empty((len(p), 7))
        J[:, :6] = _jacobian(p, n)
        J[:, 6] = ((p - transform(T, c0[None])[0]) * n).sum(axis=1)  # d r / d s: scaling about the centroid
        Jw = J.T * w
        H = Jw @ J
        try:
            x = np.linalg.solve(H + 1e-9 * np.eye(7), -(Jw @ r))
        except np.linalg.LinAlgError:
            return 1.0, float("inf")
        last = (H, max(float((w * r ** 2).sum() / w.sum()), NOISE_FLOOR ** 2), s)  # this step's normal matrix
        T = _motion(x[:6]) @ T
        s *= 1.0 + x[6]
        if not 0.5 < s < 2.0:  # ran off: the view does not hold the size
            return float(s), float("inf")
        if np.linalg.norm(x[:3]) < 1e-5 and np.linalg.norm(x[3:6]) < 1e-6 and abs(x[6]) < 1e-5:
            break
    H, var, s_step = last  # set: cfg.iterations >= 1, and every step either returns or sets it
    try:
        cov = np.linalg.inv(H + 1e-12 * np.eye(7))
    except np.linalg.LinAlgError:
        return 1.0, float("inf")
    return float(s), float(np.sqrt(max(cov[6, 6], 0.0) * var)) * s_step


def _jacobian(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(K, 6) derivative of the point-to-plane residuals ((p - q) . n) by a small motion (omega, t) of the points
    ``p`` (K, 3) with target normals ``n`` (K, 3): the rows (p x n, n)."""
    J = np.empty((len(p), 6))
    J[:, 0] = p[:, 1] * n[:, 2] - p[:, 2] * n[:, 1]
    J[:, 1] = p[:, 2] * n[:, 0] - p[:, 0] * n[:, 2]
    J[:, 2] = p[:, 0] * n[:, 1] - p[:, 1] * n[:, 0]
    J[:, 3:] = n
    return J


def _motion(x: np.ndarray) -> np.ndarray:
    """(4, 4) rigid motion of a Gauss-Newton step ``x`` = (omega (rad), t (m)), shape (6,)."""
    dT = np.eye(4)
    dT[:3, :3] = _rotvec_matrix(x[:3])
    dT[:3, 3] = x[3:]
    return dT


def _rotvec_matrix(v: np.ndarray) -> np.ndarray:
    """(3, 3) rotation by the rotation vector ``v`` (rad), by Rodrigues' formula."""
    theta = float(np.sqrt(v @ v))
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    if theta < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + (np.sin(theta) / theta) * K + ((1 - np.cos(theta)) / theta ** 2) * (K @ K)


def _pairs(source, source_normals, target, target_normals, tree, T, *, cfg, viewpoint, weights=None):
    p = transform(T, source)
    if source_normals is not None and viewpoint is not None:
        ns = source_normals @ T[:3, :3].T
        front = ((viewpoint - p) * ns).sum(axis=1) > 0
        p = p[front]
        weights = None if weights is None else weights[front]
    n_src = len(p)
    d, j = tree.query(p, distance_upper_bound=cfg.max_distance)
    ok = np.isfinite(d)
    p, j = p[ok], j[ok]
    q, n = target[j], target_normals[j]
    r = ((p - q) * n).sum(axis=1)
    u = r / cfg.kernel
    w = np.where(np.abs(u) < 1, (1 - u ** 2) ** 2, 0.0)
    if weights is not None:
        w = w * weights[ok]
    return p, q, n, w, n_src
