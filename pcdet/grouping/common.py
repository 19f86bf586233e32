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
                        diameter: float, edge_tolerance: float, normal_tolerance_deg: float, workers: int = 1
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR ``(start, deg, nbr)`` over correspondences: two are compatible when their scene pair and their model
    pair have the same point-pair feature (lengths within ``edge_tolerance`` m, the three angles within
    ``normal_tolerance_deg``). Scene pairs longer than the model's ``diameter`` or shorter than a tenth of it
    take no part.

    cand : (S, k) int64 model keypoint of each candidate, -1 where there is none.
    model_pts, model_nrm : (K, 3) model keypoints and normals.
    workers : threads that test the candidate pairs (the graph is the same for any number).
    """
    S, k = cand.shape
    M = S * k
    f0 = pairs.features[:, 0]
    near = (f0 < diameter + edge_tolerance) & (f0 > 0.1 * diameter)
    a, b, fs = pairs.a[near], pairs.b[near], pairs.features[near]
    mp = np.ascontiguousarray(model_pts, dtype=np.float32)
    mn = np.ascontiguousarray(model_nrm, dtype=np.float32)
    tol = np.float32(np.radians(normal_tolerance_deg))
    flat = cand.reshape(-1)
    lo2 = np.maximum(fs[:, 0] - edge_tolerance, 0) ** 2  # squared bounds: no square root per candidate pair
    hi2 = (fs[:, 0] + edge_tolerance) ** 2
    def test(part):
        pair, ia, ib = part
        ma, mb = flat[ia], flat[ib]
        dv = mp[mb] - mp[ma]
        l2 = np.einsum("ij,ij->i", dv, dv)
        # the cheap length test first, the angles only for what passes it
        sel = np.flatnonzero((l2 > lo2[pair]) & (l2 < hi2[pair]) & (ma != mb))
        ma, mb = ma[sel], mb[sel]
        fm = pair_features(mp[ma], mn[ma], mp[mb], mn[mb])
        d = np.abs(fs[pair[sel], 1:] - fm[:, 1:])
        keep = sel[(d[:, 0] < tol) & (d[:, 1] < tol) & (d[:, 2] < tol)]
        return ia[keep], ib[keep]

    parts = _candidate_pairs(a, b, cand)
    if workers > 1:  # the chunks are independent; their results are joined in order, so the graph is the same
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(workers) as pool:
            found = list(pool.map(test, parts))
    else:
        found = [test(p) for p in parts]
    ca_parts = [x for x, _ in found]
    cb_parts = [y for _, y in found]
    ca = np.concatenate(ca_parts) if ca_parts else np.zeros(0, np.int64)
    cb = np.concatenate(cb_parts) if cb_parts else np.zeros(0, np.int64)
    src = np.concatenate([ca, cb])
    dst = np.concatenate([cb, ca])
    order = np.lexsort((dst, src))
    src, dst = src[order], dst[order]
    deg = np.bincount(src, minlength=M)
    start = np.concatenate([[0], np.cumsum(deg)[:-1]]).astype(np.int64)
    return start, deg, dst.astype(np.int64)


def _candidate_pairs(a: np.ndarray, b: np.ndarray, cand: np.ndarray, chunk: int = 1 << 22):
    """Every (candidate of a, candidate of b) of the scene pairs (a, b), valid candidates only, in chunks of
    about ``chunk``: yields (pair index into a and b, correspondence id at a, correspondence id at b). When
    most candidates are valid, one chunk per (r1, r2) column pair; when many are missing (a colour gate left
    few), each pair's valid candidates are enumerated so that no work goes to missing ones."""
    S, k = cand.shape
    valid = cand >= 0
    if valid.mean() > 0.6:
        for r1 in range(k):
            for r2 in range(k):
                pair = np.flatnonzero(valid[a, r1] & valid[b, r2])
                yield pair, a[pair] * k + r1, b[pair] * k + r2
        return
    count = valid.sum(axis=1)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    corr = np.flatnonzero(valid.reshape(-1))  # ids (s * k + r) of the valid candidates, keypoint by keypoint
    n_ab = count[a] * count[b]
    ends = np.cumsum(n_ab)
    bounds = np.searchsorted(ends, np.arange(chunk, int(ends[-1]) if len(ends) else 0, chunk))
    for lo, hi in zip(np.concatenate([[0], bounds]), np.concatenate([bounds, [len(a)]])):
        n = n_ab[lo:hi]
        pair = np.repeat(np.arange(lo, hi), n)
        q = ramp(n)
        nb = count[b[pair]]
        yield pair, corr[first[a[pair]] + q // nb], corr[first[b[pair]] + q % nb]


def correspondence_points(scene_pts: np.ndarray, cand: np.ndarray, model_pts: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """The scene point and the model point of every correspondence: two (S * k, 3) arrays (a missing
    candidate gets model point 0; callers mask it with ``cand >= 0``)."""
    return np.repeat(scene_pts, cand.shape[1], axis=0), model_pts[np.maximum(cand.reshape(-1), 0)]


def distinct_poses(T: np.ndarray, order: np.ndarray, diameter: float, limit: int) -> np.ndarray:
    """The first ``limit`` entries of ``order`` (indices into T (B, 4, 4)) whose pose differs from every earlier
    kept one (rotation by more than 10 degrees or translation by more than a fifth of the diameter)."""
    cos10, near = np.cos(np.radians(10)), 0.2 * diameter

    def close(K: np.ndarray, C: np.ndarray) -> np.ndarray:  # (n,) whether each of C is near one of K
        c = (np.einsum("kij,nij->nk", K[:, :3, :3], C[:, :3, :3]) - 1) / 2  # cos of the relative rotations
        dt = C[:, None, :3, 3] - K[None, :, :3, 3]
        return np.any((c > cos10) & (np.einsum("nki,nki->nk", dt, dt) < near * near), axis=1)

    kept: list[int] = []
    order = np.asarray(order, np.int64)
    for i in range(0, len(order), 256):  # a run of candidates is tested against the poses kept before it at once
        chunk = order[i:i + 256]
        if kept:
            chunk = chunk[~close(T[kept], T[chunk])]
        before = len(kept)
        for b in chunk:  # then one by one against those kept within the run
            if len(kept) > before and close(T[kept[before:]], T[b][None])[0]:
                continue
            kept.append(int(b))
            if len(kept) >= limit:
                return np.array(kept, np.int64)
    return np.array(kept, np.int64)


def refit_batch(T: np.ndarray, cm: np.ndarray, cs: np.ndarray, tau: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """Robust refit of B poses (B, 4, 4) on correspondences (model cm -> scene cs, (M, 3) each): Tukey-weighted
    Kabsch with the kernel shrinking from ``tau`` to ``tau / 2``, so that wrong matches that happen to fall
    near the object do not pull a pose. Returns the poses and, for each, the indices within ``tau`` of it.

    The weighting rounds see only the correspondences within ``3 tau`` of some starting pose (the others are
    far outside every kernel); the inliers are taken among all of them."""
    T = T.copy()

    def dist(T, cm, cs):
        pred = np.matmul(cm, T[:, :3, :3].transpose(0, 2, 1)) + T[:, None, :3, 3] - cs[None]
        return np.sqrt(np.einsum("bmi,bmi->bm", pred, pred))

    d = dist(T, cm, cs)
    near = np.flatnonzero((d < 3 * tau).any(axis=0))
    sm, ss, d = cm[near], cs[near], d[:, near]
    for n, scale in enumerate((1.0, 1.0, 0.75, 0.5, 0.5)):
        if n:
            d = dist(T, sm, ss)
        c = tau * scale
        inside = d < c
        ok = inside.sum(axis=1) >= 3
        if not ok.any():
            break
        w = np.where(inside[ok], (1 - (d[ok] / c) ** 2) ** 2, 0.0) + 1e-12
        T[ok] = kabsch_shared(sm, ss, w)
    d = dist(T, cm, cs)
    return T, [np.flatnonzero(row < tau) for row in d]


def ramp(counts: np.ndarray) -> np.ndarray:
    """[0..c0-1, 0..c1-1, ...] for counts c."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    ends = np.cumsum(counts)
    return np.arange(total) - np.repeat(ends - counts, counts)
