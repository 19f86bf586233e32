"""Multi-instance RANSAC over correspondences, guided by pairwise rigid consistency; deterministic.

Correspondences come as a table: scene keypoint ``s`` has up to k candidate model keypoints ``cand[s]``.
Two correspondences are *compatible* when their scene and model point-pair features agree
(``grouping.pairs``): correct correspondences of one instance are all compatible with each other. Each round
draws seeds uniformly among active correspondences and completes each into a triplet with two of its
compatible partners that are also compatible with each other, fits the triplets by Kabsch, scores each by the
seed's compatible partners it explains, refits the best on all active inliers, and then removes its
correspondences and every correspondence on the surface it explains before the next round.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..align import kabsch, kabsch_batch, transform
from ..config import GroupingConfig
from .hypothesis import Hypothesis
from .pairs import ScenePairs, pair_features


def compatibility_graph(pairs: ScenePairs, cand: np.ndarray, model_pts: np.ndarray, model_nrm: np.ndarray,
                        diameter: float, cfg: GroupingConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR ``(start, deg, nbr)`` over correspondences ``c = s * k + r`` (scene keypoint s, r-th candidate).

    cand : (S, k) int64 model keypoint of each candidate, -1 where there is none.
    model_pts, model_nrm : (K, 3) model keypoints and normals.
    """
    S, k = cand.shape
    M = S * k
    f0 = pairs.features[:, 0]
    near = (f0 < diameter + cfg.edge_tolerance) & (f0 > 0.1 * diameter)
    a, b, fs = pairs.a[near], pairs.b[near], pairs.features[near]
    flat = cand.reshape(-1)
    # expand each scene pair into its k x k candidate pairs, testing the cheap length first
    r1, r2 = np.divmod(np.arange(k * k), k)
    ca = (a[:, None] * k + r1).reshape(-1)
    cb = (b[:, None] * k + r2).reshape(-1)
    pi = np.repeat(np.arange(len(a)), k * k)
    ma, mb = flat[ca], flat[cb]
    ok = (ma >= 0) & (mb >= 0) & (ma != mb)
    ca, cb, pi, ma, mb = ca[ok], cb[ok], pi[ok], ma[ok], mb[ok]
    lm = np.linalg.norm(model_pts[mb] - model_pts[ma], axis=1)
    ok = np.abs(fs[pi, 0] - lm) < cfg.edge_tolerance
    ca, cb, pi, ma, mb = ca[ok], cb[ok], pi[ok], ma[ok], mb[ok]
    fm = pair_features(model_pts[ma], model_nrm[ma], model_pts[mb], model_nrm[mb])
    tol = np.radians(cfg.normal_tolerance_deg)
    ok = np.abs(fs[pi, 1] - fm[:, 1]) < tol
    ok &= np.abs(fs[pi, 2] - fm[:, 2]) < tol
    ok &= np.abs(fs[pi, 3] - fm[:, 3]) < tol
    ca, cb = ca[ok], cb[ok]
    src = np.concatenate([ca, cb])
    dst = np.concatenate([cb, ca])
    order = np.lexsort((dst, src))
    src, dst = src[order], dst[order]
    deg = np.bincount(src, minlength=M)
    start = np.concatenate([[0], np.cumsum(deg)[:-1]]).astype(np.int64)
    return start, deg, dst.astype(np.int64)


def ransac_instances(scene_pts: np.ndarray, cand: np.ndarray, model_pts: np.ndarray, model_nrm: np.ndarray,
                     pairs: ScenePairs, diameter: float, cfg: GroupingConfig, rng: np.random.Generator,
                     scene_labels: np.ndarray | None = None, model_index: int = 0,
                     model_cloud: np.ndarray | None = None) -> list[Hypothesis]:
    """Hypotheses for up to ``cfg.max_instances`` instances of one model in each scene cluster.

    Parameters
    ----------
    scene_pts : (S, 3) scene keypoints (m).  cand : (S, k) candidate model keypoint indices (-1: none).
    model_pts, model_nrm : (K, 3) model keypoints (m) and normals.  pairs : scene keypoint pairs.
    diameter : model diameter (m).  scene_labels : (S,) cluster of each keypoint (None: one cluster).
    model_cloud : (P, 3) model samples used to clear the surface a found instance explains.

    Each hypothesis's ``inliers`` are correspondence indices ``s * k + r``. Clusters are searched in label
    order, so the result does not depend on anything but the inputs and ``rng``.
    """
    S, k = cand.shape
    out: list[Hypothesis] = []
    if S * k < 3:
        return out
    start, deg, nbr = compatibility_graph(pairs, cand, model_pts, model_nrm, diameter, cfg)
    cs = np.repeat(scene_pts, k, axis=0)  # scene point of each correspondence
    cm = model_pts[np.maximum(cand.reshape(-1), 0)]  # model point of each correspondence
    active = (cand.reshape(-1) >= 0) & (deg >= 2)
    labels = np.zeros(S, np.int64) if scene_labels is None else np.asarray(scene_labels)
    clabel = np.repeat(labels, k)
    for lab in np.unique(labels[active.reshape(S, k).any(axis=1)]):
        for _ in range(cfg.max_instances):
            found = _one_instance(cs, cm, k, start, deg, nbr, active & (clabel == lab), diameter, cfg, rng)
            if not found:
                break
            out += [Hypothesis(model_index, T, inl) for T, inl in found]
            Tb, inl = found[0]
            active[inl] = False
            if model_cloud is not None:  # clear the surface the best pose explains
                d, _ = cKDTree(transform(Tb, model_cloud)).query(scene_pts, distance_upper_bound=2 * cfg.inlier_distance)
                active &= ~np.repeat(np.isfinite(d), k)
    return out


def _one_instance(cs, cm, k, start, deg, nbr, active, diameter, cfg, rng) -> list[tuple[np.ndarray, np.ndarray]]:
    """The best triplet poses among ``active`` correspondences, each refit on its inliers: the best first,
    then up to ``cfg.alternatives`` others that differ from every pose before them (rotation > 10 degrees or
    translation > a fifth of the diameter), for verification to choose from. Empty when none has support."""
    pool = np.flatnonzero(active)
    if len(pool) < 3:
        return []
    i0 = pool[rng.integers(0, len(pool), cfg.iterations)]
    d0 = deg[i0]
    j = nbr[start[i0] + (rng.random(len(i0)) * d0).astype(np.int64)]
    kk = nbr[start[i0] + (rng.random(len(i0)) * d0).astype(np.int64)]
    ok = active[j] & active[kk] & (j != kk) & (j // k != kk // k)
    tri = np.stack([i0, j, kk], axis=1)[ok]
    if len(tri) == 0:
        return []
    Sx, Px = cs[tri], cm[tri]
    ds = np.linalg.norm(Sx[:, 1] - Sx[:, 2], axis=1)
    dm = np.linalg.norm(Px[:, 1] - Px[:, 2], axis=1)
    good = (np.abs(ds - dm) < cfg.edge_tolerance) & (ds > 0.1 * diameter)
    tri, Sx, Px = tri[good], Sx[good], Px[good]
    if len(tri) == 0:
        return []
    T = kabsch_batch(Px, Sx)
    # score: distinct scene keypoints among the seed's compatible partners that the pose explains
    cnt = deg[tri[:, 0]]
    rows = np.repeat(np.arange(len(tri)), cnt)
    cols = nbr[np.repeat(start[tri[:, 0]], cnt) + _ramp(cnt)]
    pred = np.einsum("nij,nj->ni", T[rows, :3, :3], cm[cols]) + T[rows, :3, 3]
    hit = active[cols] & (np.linalg.norm(pred - cs[cols], axis=1) < cfg.inlier_distance)
    n_s = len(cs) // k
    key = np.unique(rows[hit] * n_s + cols[hit] // k)
    score = np.bincount(key // n_s, minlength=len(tri))
    order = np.lexsort((np.arange(len(tri)), -score))  # best first, ties by draw order: deterministic
    found: list[tuple[np.ndarray, np.ndarray]] = []
    for b in order:
        if len(found) > cfg.alternatives or score[b] + 3 < cfg.min_inliers:
            break
        if any(_same_pose(T[b], F, diameter) for F, _ in found):
            continue
        Tb, inl = _refit(T[b], cm, cs, active, cfg.inlier_distance)
        if len(np.unique(inl // k)) < cfg.min_inliers:
            if not found:
                return []
            continue
        if not any(_same_pose(Tb, F, diameter) for F, _ in found):
            found.append((Tb, inl))
    return found


def _refit(T: np.ndarray, cm: np.ndarray, cs: np.ndarray, active: np.ndarray, tau: float):
    """Robust refit of ``T`` on the active correspondences (model cm -> scene cs): Tukey-weighted Kabsch
    with the kernel shrinking from ``tau`` to ``tau / 2``, so that wrong matches that happen to fall near the
    object do not pull the pose. Returns the pose and the correspondences within ``tau`` of it."""
    for scale in (1.0, 1.0, 0.75, 0.5, 0.5):
        d = np.linalg.norm(transform(T, cm) - cs, axis=1)
        c = tau * scale
        sel = np.flatnonzero(active & (d < c))
        if len(sel) < 3:
            break
        w = (1 - (d[sel] / c) ** 2) ** 2
        T = kabsch(cm[sel], cs[sel], w + 1e-12)
    d = np.linalg.norm(transform(T, cm) - cs, axis=1)
    return T, np.flatnonzero(active & (d < tau))


def _same_pose(A: np.ndarray, B: np.ndarray, diameter: float) -> bool:
    c = (np.trace(A[:3, :3] @ B[:3, :3].T) - 1) / 2
    return c > np.cos(np.radians(10)) and np.linalg.norm(A[:3, 3] - B[:3, 3]) < 0.2 * diameter


def _ramp(counts: np.ndarray) -> np.ndarray:
    """[0..c0-1, 0..c1-1, ...] for counts c."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    ends = np.cumsum(counts)
    return np.arange(total) - np.repeat(ends - counts, counts)
