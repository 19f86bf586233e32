"""What the groupers share: the pairwise compatibility graph over correspondences, the robust batch refit,
and the choice of distinct poses.

Correspondences come as a table: scene keypoint ``s`` has up to k candidate model keypoints ``cand[s]``
(-1: none); correspondence ``c = s * k + r`` names the r-th candidate of scene keypoint s.
"""
from __future__ import annotations

import numpy as np

from ..align import kabsch_shared
from ..pairs import ScenePairs, pair_features


def compatibility_graph(pairs: ScenePairs, cand: np.ndarray, model_pts: np.ndarray, model_nrm: np.ndarray, *,
                        diameter: float, edge_tolerance: float, normal_tolerance_deg: float
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR ``(start, deg, nbr)`` over correspondences: two are compatible when their scene pair and their model
    pair have the same point-pair feature (lengths within ``edge_tolerance`` m, the three angles within
    ``normal_tolerance_deg``). Scene pairs longer than the model's ``diameter`` or shorter than a tenth of it
    take no part.

    cand : (S, k) int64 model keypoint of each candidate, -1 where there is none.
    model_pts, model_nrm : (K, 3) model keypoints and normals.
    """
    S, k = cand.shape
    M = S * k
    f0 = pairs.features[:, 0]
    near = (f0 < diameter + edge_tolerance) & (f0 > 0.1 * diameter)
    a, b, fs = pairs.a[near], pairs.b[near], pairs.features[near]
    mp = np.ascontiguousarray(model_pts, dtype=np.float32)
    mn = np.ascontiguousarray(model_nrm, dtype=np.float32)
    tol = np.float32(np.radians(normal_tolerance_deg))
    # the candidates' model points at both ends of every pair, gathered once: (P, k, 3)
    ca_all, cb_all = cand[a], cand[b]
    pa, pb = mp[np.maximum(ca_all, 0)], mp[np.maximum(cb_all, 0)]
    lo2 = np.maximum(fs[:, 0] - edge_tolerance, 0) ** 2  # squared bounds: no square root per candidate pair
    hi2 = (fs[:, 0] + edge_tolerance) ** 2
    ca_parts, cb_parts = [], []
    # one pass per (r1, r2) candidate pair: the cheap length test first, angles only for what passes it
    for r1 in range(k):
        for r2 in range(k):
            dv = pb[:, r2] - pa[:, r1]
            l2 = np.einsum("ij,ij->i", dv, dv)
            ma, mb = ca_all[:, r1], cb_all[:, r2]
            sel = np.flatnonzero((l2 > lo2) & (l2 < hi2) & (ma >= 0) & (mb >= 0) & (ma != mb))
            ma, mb = ma[sel], mb[sel]
            fm = pair_features(mp[ma], mn[ma], mp[mb], mn[mb])
            d = np.abs(fs[sel, 1:] - fm[:, 1:])
            keep = (d[:, 0] < tol) & (d[:, 1] < tol) & (d[:, 2] < tol)
            sel = sel[keep]
            ca_parts.append(a[sel] * k + r1)
            cb_parts.append(b[sel] * k + r2)
    ca = np.concatenate(ca_parts) if ca_parts else np.zeros(0, np.int64)
    cb = np.concatenate(cb_parts) if cb_parts else np.zeros(0, np.int64)
    src = np.concatenate([ca, cb])
    dst = np.concatenate([cb, ca])
    order = np.lexsort((dst, src))
    src, dst = src[order], dst[order]
    deg = np.bincount(src, minlength=M)
    start = np.concatenate([[0], np.cumsum(deg)[:-1]]).astype(np.int64)
    return start, deg, dst.astype(np.int64)


def correspondence_points(scene_pts: np.ndarray, cand: np.ndarray, model_pts: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """The scene point and the model point of every correspondence: two (S * k, 3) arrays (a missing
    candidate gets model point 0; callers mask it with ``cand >= 0``)."""
    return np.repeat(scene_pts, cand.shape[1], axis=0), model_pts[np.maximum(cand.reshape(-1), 0)]


def distinct_poses(T: np.ndarray, order: np.ndarray, diameter: float, limit: int) -> np.ndarray:
    """The first ``limit`` entries of ``order`` (indices into T (B, 4, 4)) whose pose differs from every earlier
    kept one (rotation by more than 10 degrees or translation by more than a fifth of the diameter)."""
    kept: list[int] = []
    cos10 = np.cos(np.radians(10))
    for b in order:
        if kept:
            K = T[kept]
            c = (np.einsum("nij,ij->n", K[:, :3, :3], T[b, :3, :3]) - 1) / 2  # cos of the relative rotation
            close = np.linalg.norm(K[:, :3, 3] - T[b, :3, 3], axis=1) < 0.2 * diameter
            if np.any((c > cos10) & close):
                continue
        kept.append(int(b))
        if len(kept) >= limit:
            break
    return np.array(kept, np.int64)


def refit_batch(T: np.ndarray, cm: np.ndarray, cs: np.ndarray, tau: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """Robust refit of B poses (B, 4, 4) on correspondences (model cm -> scene cs, (M, 3) each): Tukey-weighted
    Kabsch with the kernel shrinking from ``tau`` to ``tau / 2``, so that wrong matches that happen to fall
    near the object do not pull a pose. Returns the poses and, for each, the indices within ``tau`` of it."""
    T = T.copy()
    for scale in (1.0, 1.0, 0.75, 0.5, 0.5):
        pred = np.matmul(cm, T[:, :3, :3].transpose(0, 2, 1)) + T[:, None, :3, 3]
        d = np.sqrt(((pred - cs[None]) ** 2).sum(axis=2))
        c = tau * scale
        inside = d < c
        ok = inside.sum(axis=1) >= 3
        if not ok.any():
            break
        w = np.where(inside[ok], (1 - (d[ok] / c) ** 2) ** 2, 0.0) + 1e-12
        T[ok] = kabsch_shared(cm, cs, w)
    pred = np.matmul(cm, T[:, :3, :3].transpose(0, 2, 1)) + T[:, None, :3, 3]
    d = np.sqrt(((pred - cs[None]) ** 2).sum(axis=2))
    return T, [np.flatnonzero(row < tau) for row in d]


def ramp(counts: np.ndarray) -> np.ndarray:
    """[0..c0-1, 0..c1-1, ...] for counts c."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    ends = np.cumsum(counts)
    return np.arange(total) - np.repeat(ends - counts, counts)
