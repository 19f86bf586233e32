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

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..align import kabsch_batch, kabsch_shared, transform
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
    mp = np.ascontiguousarray(model_pts, dtype=np.float32)
    mn = np.ascontiguousarray(model_nrm, dtype=np.float32)
    tol = np.float32(np.radians(cfg.normal_tolerance_deg))
    ca_parts, cb_parts = [], []
    # one pass per (r1, r2) candidate pair: small temporaries, and the cheap length test first
    for r1 in range(k):
        ma_all = cand[a, r1]
        for r2 in range(k):
            mb_all = cand[b, r2]
            ok = (ma_all >= 0) & (mb_all >= 0) & (ma_all != mb_all)
            sel = np.flatnonzero(ok)
            ma, mb = ma_all[sel], mb_all[sel]
            dv = mp[mb] - mp[ma]
            lm = np.sqrt(np.einsum("ij,ij->i", dv, dv))
            keep = np.abs(fs[sel, 0] - lm) < cfg.edge_tolerance
            sel, ma, mb = sel[keep], ma[keep], mb[keep]
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


def ransac_instances(scene_pts: np.ndarray, cand: np.ndarray, model_pts: np.ndarray, model_nrm: np.ndarray,
                     pairs: ScenePairs, diameter: float, cfg: GroupingConfig, rng: np.random.Generator,
                     scene_labels: np.ndarray | None = None, model_index: int = 0,
                     model_cloud: np.ndarray | None = None, overlap: "Overlap | None" = None,
                     scene_nrm: np.ndarray | None = None) -> list[Hypothesis]:
    """Hypotheses for up to ``cfg.max_instances`` instances of one model in each scene cluster.

    Parameters
    ----------
    scene_pts : (S, 3) scene keypoints (m).  cand : (S, k) candidate model keypoint indices (-1: none).
    model_pts, model_nrm : (K, 3) model keypoints (m) and normals.  pairs : scene keypoint pairs.
    diameter : model diameter (m).  scene_labels : (S,) cluster of each keypoint (None: one cluster).
    model_cloud : (P, 3) model samples used to clear the surface a found instance explains.
    overlap : when given, the best triplet poses are re-ranked by how much of the model they lay on the scene.
    scene_nrm : (S, 3) scene keypoint normals; with them, triplets on one flat patch are not drawn.

    Each hypothesis's ``inliers`` are correspondence indices ``s * k + r``. Clusters are searched in label
    order, so the result does not depend on anything but the inputs and ``rng``.
    """
    S, k = cand.shape
    out: list[Hypothesis] = []
    if S * k < 3:
        return out
    start, deg, nbr = compatibility_graph(pairs, cand, model_pts, model_nrm, diameter, cfg)
    cs = np.repeat(scene_pts, k, axis=0)  # scene point of each correspondence
    cn = None if scene_nrm is None else np.repeat(scene_nrm, k, axis=0)
    cm = model_pts[np.maximum(cand.reshape(-1), 0)]  # model point of each correspondence
    active = (cand.reshape(-1) >= 0) & (deg >= 2)
    labels = np.zeros(S, np.int64) if scene_labels is None else np.asarray(scene_labels)
    clabel = np.repeat(labels, k)
    for lab in np.unique(labels[active.reshape(S, k).any(axis=1)]):
        for _ in range(cfg.max_instances):
            found = _one_instance(cs, cm, k, start, deg, nbr, active & (clabel == lab), diameter, cfg, rng, overlap,
                                  cn)
            if not found:
                break
            out += [Hypothesis(model_index, T, inl, len(inl)) for T, inl in found]
            Tb, inl = found[0]
            active[inl] = False
            if model_cloud is not None:  # clear the surface the best pose explains
                d, _ = cKDTree(transform(Tb, model_cloud)).query(scene_pts, distance_upper_bound=2 * cfg.inlier_distance)
                active &= ~np.repeat(np.isfinite(d), k)
    return out


@dataclass
class Overlap:
    """Geometric overlap of a posed model with the scene (the largest-common-pointset score of 4PCS):
    the number of model samples facing the camera that lie within ``distance`` of a scene point.

    points, normals : (P, 3) model samples and outward normals (model frame, m); scene_tree : KD-tree of the
    scene points (camera frame).
    """

    points: np.ndarray
    normals: np.ndarray
    scene_tree: cKDTree
    distance: float

    def __call__(self, T: np.ndarray) -> int:
        P = self.points @ T[:3, :3].T + T[:3, 3]
        front = ((self.normals @ T[:3, :3].T) * P).sum(axis=1) < 0
        d, _ = self.scene_tree.query(P[front], distance_upper_bound=self.distance)
        return int(np.isfinite(d).sum())


def _one_instance(cs, cm, k, start, deg, nbr, active, diameter, cfg, rng, overlap=None, cn=None
                  ) -> list[tuple[np.ndarray, np.ndarray]]:
    """The best triplet poses among ``active`` correspondences, each refit on its inliers: the best first,
    then up to ``cfg.alternatives`` others that differ from every pose before them (rotation > 10 degrees or
    translation > a fifth of the diameter), for verification to choose from. Empty when none has support.

    Triplets are ranked by the distinct scene keypoints they explain among the seed's compatible partners; with
    an ``overlap`` score, the ``cfg.rescore`` best of them are refit and re-ranked by it."""
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
    if cn is not None and cfg.min_normal_spread_deg > 0:
        # three points on one flat patch carry no shape: their descriptors match any flat part of the model,
        # and every such triplet is rigidly consistent. Ask for at least one normal off the others.
        Nx = cn[tri]
        c = np.cos(np.radians(cfg.min_normal_spread_deg))
        flat = (((Nx[:, 0] * Nx[:, 1]).sum(1) > c) & ((Nx[:, 0] * Nx[:, 2]).sum(1) > c)
                & ((Nx[:, 1] * Nx[:, 2]).sum(1) > c))
        good &= ~flat
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
    order = order[score[order] + 3 >= cfg.min_inliers]
    limit = cfg.rescore if overlap is not None else cfg.alternatives + 1
    lead = _distinct(T, order, diameter, limit)
    if len(lead) == 0:
        return []
    Tr, inls = refit_batch(T[lead], cm[pool], cs[pool], cfg.inlier_distance)
    n_pts = np.array([len(np.unique(pool[i] // k)) for i in inls])
    keep = np.flatnonzero(n_pts >= cfg.min_inliers)
    if len(keep) == 0:
        return []
    if overlap is not None and len(keep) > 1:
        lcp = np.array([overlap(Tr[i]) for i in keep])
        keep = keep[np.lexsort((keep, -lcp))]
    keep = _distinct(Tr, keep, diameter, cfg.alternatives + 1)
    return [(Tr[i], pool[inls[i]]) for i in keep]


def _distinct(T: np.ndarray, order: np.ndarray, diameter: float, limit: int) -> np.ndarray:
    """The first ``limit`` entries of ``order`` (indices into T) whose pose differs from every earlier kept one
    (rotation by more than 10 degrees or translation by more than a fifth of the diameter)."""
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


def _ramp(counts: np.ndarray) -> np.ndarray:
    """[0..c0-1, 0..c1-1, ...] for counts c."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    ends = np.cumsum(counts)
    return np.arange(total) - np.repeat(ends - counts, counts)
