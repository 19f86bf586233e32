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
    places: int = param(3, "with targets: a model's coarse ICPs, and then its full ICPs, cover at least this many "
                           "places of the scene (posed centroids half its diameter apart), one more ICP for each "
                           "place the candidates or max_per_model best leave out (0: off)")
    retry_places: int = param(1, "with targets: a given object left with fewer poses than wanted after selection "
                                 "has its best-looking coarse candidates at up to this many new places refined "
                                 "fully, and selection runs again (0: off)")

    def __post_init__(self):
        check_positive(self, "iterations", "max_distance", "kernel", "max_per_model", "coarse_distance",
                       "coarse_points")
        for n in ("candidates", "places", "retry_places"):
            if getattr(self, n) < 0:
                raise ConfigError(f"RefineConfig.{n} must be >= 0, got {getattr(self, n)}")


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
    return icp_many([source], target, target_normals, [T_init], cfg, source_normals=[source_normals],
                    target_tree=target_tree, viewpoint=viewpoint, tolerance=tolerance, weights=[weights])[0]


def icp_many(sources: list[np.ndarray], target: np.ndarray, target_normals: np.ndarray, T_inits: list[np.ndarray],
             cfg: RefineConfig, *, source_normals: list[np.ndarray | None] | None = None,
             target_tree: cKDTree | None = None, viewpoint: np.ndarray | None = None,
             tolerance: tuple[float, float] = (1e-5, 1e-6), weights: list[np.ndarray | None] | None = None,
             workers: int = 1) -> list[RegistrationResult]:
    """``icp`` of B problems onto one target: ``sources[b]`` (N_b, 3) from ``T_inits[b]`` (4, 4), with
    ``source_normals[b]`` and ``weights[b]`` (each may be None), as B calls of ``icp`` would give them, bit for
    bit: each problem steps on its own (its own stop, its own normal equations); what is per point (moving the
    samples, the nearest target point, residuals, kernel weights, Jacobian rows) is done for all problems at once,
    and the nearest-point queries of an iteration are one KD-tree call on ``workers`` threads (each query on its
    own: the same on any number). For the many short ICPs of a frame's hypotheses, whose time went to a few
    dozen small array steps per iteration and problem."""
    B = len(sources)
    if B == 0:
        return []
    nrm = list(source_normals) if source_normals is not None else [None] * B
    wts = list(weights) if weights is not None else [None] * B
    tree = target_tree if target_tree is not None else cKDTree(target)
    T = [np.asarray(t, float).copy() for t in T_inits]
    its, converged, running = [0] * B, [False] * B, list(range(B))
    for it in range(1, cfg.iterations + 1):
        if not running:
            break
        pairs = _pairs_many(sources, nrm, target, target_normals, tree, T, which=running, cfg=cfg, viewpoint=viewpoint,
                            weights=wts, workers=workers)
        J = _jacobian(pairs.p, pairs.n)
        still = []
        for b, (a, e) in zip(running, pairs.spans):
            its[b] = it
            if e - a < 6:
                continue
            Jw = J[a:e].T * pairs.w[a:e]
            try:
                x = np.linalg.solve(Jw @ J[a:e] + 1e-9 * np.eye(6), -(Jw @ pairs.r[a:e]))
            except np.linalg.LinAlgError:
                continue
            T[b] = _motion(x) @ T[b]
            if np.linalg.norm(x[:3]) < tolerance[0] and np.linalg.norm(x[3:]) < tolerance[1]:
                converged[b] = True
                continue
            still.append(b)
        running = still
    final = _pairs_many(sources, nrm, target, target_normals, tree, T, which=list(range(B)), cfg=cfg,
                        viewpoint=viewpoint, weights=None, workers=workers)
    out = []
    for b, ((a, e), n_src) in enumerate(zip(final.spans, final.n_src)):
        r = final.r[a:e]
        rmse = float(np.sqrt((r ** 2).mean())) if len(r) else float("inf")
        out.append(RegistrationResult(T[b], len(r) / max(n_src, 1), rmse, len(r), its[b], converged[b]))
    return out


@dataclass
class _Pairs:
    """The matched pairs of several ICP problems, concatenated: source points p, target points q and normals n
    (P, 3), residuals r and kernel weights w (P,); ``spans[i]`` the (start, end) of the i-th problem asked for,
    ``n_src[i]`` its source points that took part (facing the viewpoint)."""

    p: np.ndarray
    q: np.ndarray
    n: np.ndarray
    r: np.ndarray
    w: np.ndarray
    spans: list[tuple[int, int]]
    n_src: list[int]


def _pairs_many(sources, source_normals, target, target_normals, tree, T, *, which: list[int], cfg, viewpoint,
                weights, workers: int = 1) -> _Pairs:
    """``_pairs`` of the problems ``which`` (indices into the per-problem lists), the per-point steps on all of
    them at once; row for row the same numbers as one ``_pairs`` call per problem."""
    ps, ws, n_src = [], [], []
    for b in which:
        p = transform(T[b], sources[b])
        if source_normals[b] is not None and viewpoint is not None:
            ns = source_normals[b] @ T[b][:3, :3].T
            front = ((viewpoint - p) * ns).sum(axis=1) > 0
            p = p[front]
            w = None if weights is None or weights[b] is None else weights[b][front]
        else:
            w = None if weights is None else weights[b]
        ps.append(p)
        ws.append(w)
        n_src.append(len(p))
    p = np.concatenate(ps) if ps else np.zeros((0, 3))
    d, j = tree.query(p, distance_upper_bound=cfg.max_distance, workers=workers)
    ok = np.isfinite(d)
    p, j = p[ok], j[ok]
    q, n = target[j], target_normals[j]
    r = ((p - q) * n).sum(axis=1)
    u = r / cfg.kernel
    w = np.where(np.abs(u) < 1, (1 - u ** 2) ** 2, 0.0)
    ends = np.cumsum(n_src)
    kept = np.r_[0, np.cumsum(ok)][np.r_[0, ends]]  # matched points before each problem's first
    spans = [(int(kept[i]), int(kept[i + 1])) for i in range(len(which))]
    for (a, e), wb, o in zip(spans, ws, np.split(ok, ends[:-1])):
        if wb is not None:
            w[a:e] = w[a:e] * wb[o]
    return _Pairs(p, q, n, r, w, spans, n_src)


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
    """(p, q, n, w, n_src) of one problem (``_pairs_many``)."""
    pr = _pairs_many([source], [source_normals], target, target_normals, tree, [T], which=[0], cfg=cfg,
                     viewpoint=viewpoint, weights=[weights])
    return pr.p, pr.q, pr.n, pr.w, pr.n_src[0]
