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
from .pairs import ScenePairs, compatible


def compatibility_graph(pairs: ScenePairs, cand: np.ndarray, table: np.ndarray, diameter: float,
                        cfg: GroupingConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR ``(start, deg, nbr)`` over correspondences ``c = s * k + r`` (scene keypoint s, r-th candidate).

    cand : (S, k) int64 model keypoint of each candidate, -1 where there is none.
    table : (K, K, 4) model pair features.
    """
    S, k = cand.shape
    M = S * k
    near = pairs.features[:, 0] < diameter
    a, b, fs = pairs.a[near], pairs.b[near], pairs.features[near]
    r1, r2 = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    r1, r2 = r1.reshape(-1), r2.reshape(-1)
    ca = (a[:, None] * k + r1).reshape(-1)
    cb = (b[:, None] * k + r2).reshape(-1)
    ma, mb = cand.reshape(-1)[ca], cand.reshape(-1)[cb]
    fsx = np.repeat(fs, k * k, axis=0)
    ok = (ma >= 0) & (mb >= 0) & (ma != mb)
    ok[ok] = compatible(fsx[ok], table[ma[ok], mb[ok]], cfg.edge_tolerance,
                        np.radians(cfg.normal_tolerance_deg), 0.1 * diameter)
    ca, cb = ca[ok], cb[ok]
    src = np.concatenate([ca, cb])
    dst = np.concatenate([cb, ca])
    order = np.lexsort((dst, src))
    src, dst = src[order], dst[order]
    deg = np.bincount(src, minlength=M)
    start = np.concatenate([[0], np.cumsum(deg)[:-1]]).astype(np.int64)
    return start, deg, dst.astype(np.int64)


def ransac_instances(scene_pts: np.ndarray, cand: np.ndarray, model_pts: np.ndarray, pairs: ScenePairs,
                     table: np.ndarray, diameter: float, cfg: GroupingConfig, rng: np.random.Generator,
                     model_index: int = 0, model_cloud: np.ndarray | None = None) -> list[Hypothesis]:
    """Hypotheses for up to ``cfg.max_instances`` instances of one model.

    Parameters
    ----------
    scene_pts : (S, 3) scene keypoints (m).  cand : (S, k) candidate model keypoint indices (-1: none).
    model_pts : (K, 3) model keypoints (m).  pairs, table : scene pairs and model pair-feature table.
    diameter : model diameter (m).  model_cloud : (P, 3) model samples used to clear an explained surface.

    Each hypothesis's ``inliers`` are correspondence indices ``s * k + r``.
    """
    S, k = cand.shape
    M = S * k
    out: list[Hypothesis] = []
    if M < 3:
        return out
    start, deg, nbr = compatibility_graph(pairs, cand, table, diameter, cfg)
    cs = np.repeat(scene_pts, k, axis=0)  # scene point of each correspondence
    cm = model_pts[np.maximum(cand.reshape(-1), 0)]  # model point of each correspondence
    valid = cand.reshape(-1) >= 0
    active = valid & (deg >= 2)
    for _ in range(cfg.max_instances):
        pool = np.flatnonzero(active)
        if len(pool) == 0:
            break
        i0 = pool[rng.integers(0, len(pool), cfg.iterations)]
        d0 = deg[i0]
        j = nbr[start[i0] + (rng.random(len(i0)) * d0).astype(np.int64)]
        kk = nbr[start[i0] + (rng.random(len(i0)) * d0).astype(np.int64)]
        ok = active[j] & active[kk] & (j != kk) & (j // k != kk // k)
        tri = np.stack([i0, j, kk], axis=1)[ok]
        if len(tri) == 0:
            break
        Sx, Px = cs[tri], cm[tri]
        ds = np.linalg.norm(Sx[:, 1] - Sx[:, 2], axis=1)
        dm = np.linalg.norm(Px[:, 1] - Px[:, 2], axis=1)
        good = (np.abs(ds - dm) < cfg.edge_tolerance) & (ds > 0.1 * diameter)
        tri, Sx, Px = tri[good], Sx[good], Px[good]
        if len(tri) == 0:
            break
        T = kabsch_batch(Px, Sx)
        cnt = deg[tri[:, 0]]
        rows = np.repeat(np.arange(len(tri)), cnt)
        cols = nbr[np.repeat(start[tri[:, 0]], cnt) + _ramp(cnt)]
        pred = np.einsum("nij,nj->ni", T[rows, :3, :3], cm[cols]) + T[rows, :3, 3]
        hit = active[cols] & (np.linalg.norm(pred - cs[cols], axis=1) < cfg.inlier_distance)
        # count distinct scene keypoints explained, not candidates (k candidates of one point may all fit)
        key = np.unique(rows[hit] * S + cols[hit] // k)
        score = np.bincount(key // S, minlength=len(tri))
        best = int(np.argmax(score))  # first maximum: deterministic
        Tb = T[best]
        inl = np.zeros(0, np.int64)
        for _ in range(3):  # refit on all active inliers
            inl = np.flatnonzero(active & (np.linalg.norm(transform(Tb, cm) - cs, axis=1) < cfg.inlier_distance))
            if len(inl) < 3:
                break
            Tb = kabsch(cm[inl], cs[inl])
        n_pts = len(np.unique(inl // k))
        if n_pts < cfg.min_inliers:
            break
        out.append(Hypothesis(model_index, Tb, inl))
        active[inl] = False
        if model_cloud is not None:  # clear the surface this instance explains
            d, _ = cKDTree(transform(Tb, model_cloud)).query(scene_pts, distance_upper_bound=2 * cfg.inlier_distance)
            active &= ~np.repeat(np.isfinite(d), k)
    return out


def _ramp(counts: np.ndarray) -> np.ndarray:
    """[0..c0-1, 0..c1-1, ...] for counts c."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    ends = np.cumsum(counts)
    return np.arange(total) - np.repeat(ends - counts, counts)
