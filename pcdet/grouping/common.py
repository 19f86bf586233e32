"""What the groupers share: the pairwise compatibility graph over correspondences, the robust batch refit,
and the choice of distinct poses.

Correspondences come as a table: scene keypoint ``s`` has up to k candidate model keypoints ``cand[s]``
(-1: none); correspondence ``c = s * k + r`` names the r-th candidate of scene keypoint s.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sparse

from ..align import greedy_distinct
from ..graph import compatible_pairs, compiled, length_matches
from ..pairs import ScenePairs, pair_features
from ..residuals import tukey_step, within


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
    angles = fs[:, [3, 1, 2]]  # in the order the angle test takes them
    def angles_agree(pair, ma, mb):  # (n,) bool: the three angles of scene and model pairs agree
        # the normals' angle first: it needs no pair vector and refuses more than half; the other two after
        n1, n2 = mn[ma], mn[mb]
        ok = np.abs(fs[pair, 3] - np.arccos(np.clip(np.einsum("...i,...i->...", n1, n2), -1, 1))) < tol
        i = np.flatnonzero(ok)
        fm = pair_features(mp[ma[i]], n1[i], mp[mb[i]], n2[i])
        d = np.abs(fs[pair[i], 1:3] - fm[:, 1:3])
        ok[i] = (d[:, 0] < tol) & (d[:, 1] < tol)
        return ok

    def test(part):  # (pair index, correspondence id at a, at b) listed one by one (sparse candidates)
        pair, ia, ib = part
        ma, mb = flat[ia], flat[ib]
        dv = mp[mb] - mp[ma]
        l2 = np.einsum("ij,ij->i", dv, dv)
        # the cheap length test first, the angles only for what passes it
        sel = np.flatnonzero((l2 > lo2[pair]) & (l2 < hi2[pair]) & (ma != mb))
        keep = sel[angles_agree(pair[sel], ma[sel], mb[sel])]
        return ia[keep], ib[keep]

    def test_rows(rows):  # every candidate of a against every candidate of b, for a block of scene pairs
        if compiled():  # both tests in the kernel, which leaves numpy the angle tests too close to call
            ia, ib, p, ua, ub = compatible_pairs(a[rows], b[rows], lo2[rows], hi2[rows], cand, mp, normals=mn,
                                                 angles=angles[rows], tol=tol)
            keep = angles_agree(rows[p], flat[ua], flat[ub])
            return np.concatenate([ia, ua[keep]]), np.concatenate([ib, ub[keep]])
        # the length test first (numpy's length_matches), the angles for what passes
        p, ia, ib = length_matches(a[rows], b[rows], lo2[rows], hi2[rows], cand, mp)
        keep = angles_agree(rows[p], flat[ia], flat[ib])
        return ia[keep], ib[keep]

    if (cand >= 0).mean() > 0.6:  # most candidates valid: blocks of scene pairs, all k x k candidate pairs
        step = max(1, (1 << 19) // k)
        blocks = [np.arange(lo, min(lo + step, len(a))) for lo in range(0, len(a), step)]
        fn, parts = test_rows, blocks
    else:
        fn, parts = test, _candidate_pairs(a, b, cand)
    if workers > 1:  # the chunks are independent; the graph is sorted below, so it is the same for any number
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(workers) as pool:
            found = list(pool.map(fn, parts))
    else:
        found = [fn(p) for p in parts]
    ca = np.concatenate([x for x, _ in found] or [np.zeros(0, np.int64)])
    cb = np.concatenate([y for _, y in found] or [np.zeros(0, np.int64)])
    # both directions, by first end and then second (each pair is found once, so the order is unique): scipy's
    # CSR build is a counting sort by row and then sorts each row's columns, linear where a lexsort was not
    A = sparse.csr_matrix((np.ones(2 * len(ca), np.float32), (np.r_[ca, cb], np.r_[cb, ca])), shape=(M, M))
    A.sort_indices()
    return A.indptr[:-1].astype(np.int64), np.diff(A.indptr).astype(np.int64), A.indices.astype(np.int64)


def _candidate_pairs(a: np.ndarray, b: np.ndarray, cand: np.ndarray, chunk: int = 1 << 22):
    """Every (valid candidate of a, valid candidate of b) of the scene pairs (a, b), in chunks of about
    ``chunk``: yields (pair index into a and b, correspondence id at a, correspondence id at b). For candidate
    tables with many missing entries (a colour gate left few): no work goes to missing ones."""
    S, k = cand.shape
    valid = cand >= 0
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


def distinct_poses(T: np.ndarray, order: np.ndarray, diameter: float, limit: int, *, use_compiled: bool = True
                   ) -> np.ndarray:
    """The first ``limit`` entries of ``order`` (indices into T (B, 4, 4)) whose pose differs from every earlier
    kept one (rotation by more than 10 degrees or translation by more than a fifth of the diameter).

    Greedy, in order: the compiled kernel (``pcdet/_align.c``) walks ``order`` and stops at ``limit``; numpy
    (``use_compiled`` False, or no kernel built) tests runs of 256 at once. The two sum trace(Ra^T Rb) in their own
    orders, so a pair within a last bit of 10 degrees can be judged apart by one and near by the other."""
    cos10, near2 = np.cos(np.radians(10)), (0.2 * diameter) ** 2
    order = np.asarray(order, np.int64)
    kept = greedy_distinct(T, order, cos10, near2, limit) if use_compiled else None
    if kept is not None:
        return kept
    R, t = T[:, :3, :3].reshape(len(T), 9), T[:, :3, 3]

    def close(A: np.ndarray, C: np.ndarray) -> np.ndarray:  # (len(A), len(C)): whether A[a] is near C[c]
        c = (R[A] @ R[C].T - 1) / 2  # cos of the relative rotations: (trace(Ra^T Rc) - 1) / 2
        dt = t[A][:, None, :] - t[C][None, :, :]
        return (c > cos10) & (np.einsum("aci,aci->ac", dt, dt) < near2)

    kept = np.zeros(0, np.int64)
    for i in range(0, len(order), 256):  # a run of candidates is tested against the poses kept before it at once
        chunk = order[i:i + 256]
        if len(kept):
            chunk = chunk[~close(kept, chunk).any(axis=0)]
        near = close(chunk, chunk)  # then greedily within the run: a kept pose blocks those near it
        blocked = np.zeros(len(chunk), bool)
        take: list[int] = []
        for j in range(len(chunk)):
            if blocked[j]:
                continue
            take.append(j)
            if len(kept) + len(take) >= limit:
                break
            blocked |= near[j]
        kept = np.concatenate([kept, chunk[take]])
        if len(kept) >= limit:
            break
    return kept


def distinct_surfaces(T: np.ndarray, order, points: np.ndarray, diameter: float, limit: int, *,
                      fraction: float = 0.1) -> np.ndarray:
    """The first ``limit`` entries of ``order`` (indices into T (B, 4, 4)) whose placed surface differs from that
    of every earlier kept one: the model samples ``points`` (M, 3) placed by one lie a mean of ``fraction *
    diameter`` or more from their closest samples placed by the other (the ADD-S distance). So poses that
    differ by a symmetry of the object (a box turned over, a can turned about its axis) are one: they put the
    same surface on the same spot of the scene, where ``distinct_poses`` keeps them apart."""
    order = np.asarray(order, np.int64)
    tol = fraction * diameter
    P = np.einsum("bij,mj->bmi", T[order, :3, :3], points) + T[order, None, :3, 3]  # (len(order), M, 3)
    c = P.mean(axis=1)
    kept: list[int] = []
    for a in range(len(order)):
        if any(np.sum((c[a] - c[b]) ** 2) < tol * tol  # centroids apart: surfaces apart, no closer look needed
               and np.sqrt(np.sum((P[a][:, None, :] - P[b][None, :, :]) ** 2, axis=2).min(axis=1)).mean() < tol
               for b in kept):
            continue
        kept.append(a)
        if len(kept) >= limit:
            break
    return order[kept]


def refit_batch(T: np.ndarray, cm: np.ndarray, cs: np.ndarray, tau: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """Robust refit of B poses (B, 4, 4) on correspondences (model cm -> scene cs, (M, 3) each): Tukey-weighted
    Kabsch with the kernel shrinking from ``tau`` to ``tau / 2``, so that wrong matches that happen to fall
    near the object do not pull a pose. Returns the poses and, for each, the indices within ``tau`` of it.

    The weighting rounds see only the correspondences within ``3 tau`` of some starting pose (the others are
    far outside every kernel); the inliers are taken among all of them."""
    T = np.asarray(T, dtype=np.float64)  # not written to: each step returns new poses
    near = np.zeros(len(cm), bool)  # marked, not sorted: the union of the poses' sets
    for idx in within(T, cm, cs, 3 * tau):
        near[idx] = True
    sm, ss = cm[near], cs[near]
    for scale in (1.0, 1.0, 0.75, 0.5, 0.5):
        ok, T = tukey_step(T, sm, ss, tau * scale)
        if not ok.any():
            break
    return T, within(T, cm, cs, tau)


def ramp(counts: np.ndarray) -> np.ndarray:
    """[0..c0-1, 0..c1-1, ...] for counts c."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    ends = np.cumsum(counts)
    return np.arange(total) - np.repeat(ends - counts, counts)
