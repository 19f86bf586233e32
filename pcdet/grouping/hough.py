"""6-DoF Hough voting for correspondence grouping, after Tombari and Di Stefano (PSIVT 2010).

Each model keypoint stores the offset to the model's reference point in its own local reference frame. A
correspondence (scene keypoint s with frame F_s, model keypoint m with frame F_m) votes for where the
reference point lies in the scene: s + F_s^T F_m (c - m), and for the rotation F_s^T F_m. Votes go into a 3D
grid with trilinear interpolation; every local maximum with at least ``hough_min_votes`` is a candidate. Its
voters (correspondences whose predicted reference point falls within one bin of the peak) are then required to
agree on the rotation too, which makes the grouping 6-DoF: the voter whose rotation has the most others within
``hough_rotation_tol_deg`` (among at most 64 evenly spaced voters) anchors the group, the group is fitted by
robust Kabsch, and candidates that describe the same instance are merged (largest first). Deterministic: no
random draws.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..align import kabsch
from ..config import GroupingConfig
from .hypothesis import Hypothesis
from .ransac import _distinct, refit_batch


def hough_groups(scene_pts: np.ndarray, scene_lrf: np.ndarray, cand: np.ndarray, model_pts: np.ndarray,
                 model_lrf: np.ndarray, reference: np.ndarray, diameter: float, cfg: GroupingConfig,
                 model_index: int = 0, max_groups: int = 12, stats: dict | None = None) -> list[Hypothesis]:
    """Hypotheses from Hough votes of the correspondences ``c = s * k + r``.

    scene_pts : (S, 3) and scene_lrf : (S, 3, 3) (rows x, y, z; NaN where invalid); cand : (S, k) model
    keypoint per candidate (-1: none); model_pts : (K, 3), model_lrf : (K, 3, 3); reference : (3,) the model
    point votes are cast for (m). ``stats``, when given, receives the vote count and group size of each kept
    hypothesis.
    """
    S, k = cand.shape
    flat = cand.reshape(-1)
    corr = np.flatnonzero(flat >= 0)
    si, mi = corr // k, flat[corr]
    ok = ~np.isnan(scene_lrf[si, 0, 0]) & ~np.isnan(model_lrf[mi, 0, 0])
    corr, si, mi = corr[ok], si[ok], mi[ok]
    if len(corr) < cfg.min_inliers:
        return []
    Fs, Fm = scene_lrf[si], model_lrf[mi]
    local = np.einsum("nij,nj->ni", Fm, reference - model_pts[mi])  # offset in the model keypoint's frame
    centre = scene_pts[si] + np.einsum("nji,nj->ni", Fs, local)  # back to the scene: F_s^T local
    rot = np.einsum("nji,njk->nik", Fs, Fm)  # F_s^T F_m: model frame -> scene frame
    # trilinear voting into a sparse 3D grid
    b = cfg.hough_bin
    g = centre / b - 0.5
    base = np.floor(g).astype(np.int64)
    frac = g - base
    keys, weights = [], []
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = (np.where(dx, frac[:, 0], 1 - frac[:, 0]) * np.where(dy, frac[:, 1], 1 - frac[:, 1])
                     * np.where(dz, frac[:, 2], 1 - frac[:, 2]))
                keys.append(base + [dx, dy, dz])
                weights.append(w)
    cells = np.concatenate(keys)
    # one int64 key per cell (a 1-D unique is far faster than unique rows)
    lo = cells.min(axis=0)
    span = cells.max(axis=0) - lo + 1
    code = ((cells[:, 0] - lo[0]) * span[1] + (cells[:, 1] - lo[1])) * span[2] + (cells[:, 2] - lo[2])
    ucode, inv = np.unique(code, return_inverse=True)
    uniq = np.column_stack([ucode // (span[1] * span[2]), ucode // span[2] % span[1], ucode % span[2]]) + lo
    votes = np.bincount(inv.reshape(-1), weights=np.concatenate(weights))
    # local maxima over the 26-neighbourhood
    lookup = {tuple(c): v for c, v in zip(uniq.tolist(), votes)}
    offsets = [(i, j, l) for i in (-1, 0, 1) for j in (-1, 0, 1) for l in (-1, 0, 1) if (i, j, l) != (0, 0, 0)]
    peaks = []
    for c, v in sorted(zip(map(tuple, uniq.tolist()), votes), key=lambda x: (-x[1], x[0])):
        if v < cfg.hough_min_votes:
            break
        if all(lookup.get((c[0] + i, c[1] + j, c[2] + l), 0.0) <= v for i, j, l in offsets):
            peaks.append((np.array(c, float), v))
    if not peaks:
        return []
    tree = cKDTree(centre)
    cos_tol = np.cos(np.radians(cfg.hough_rotation_tol_deg))
    cands, meta = [], []
    for cell, v in peaks[: 4 * max_groups]:
        # voters: predicted reference points near the peak (grid index c sits at (c + 0.5) * bin)
        voters = np.array(tree.query_ball_point((cell + 0.5) * b, 1.5 * b), dtype=np.int64)
        if len(voters) < cfg.min_inliers:
            continue
        Rv = rot[voters]
        # anchor candidates: all voters, or an evenly spaced 64 of them when there are more (deterministic)
        anchors = np.unique(np.linspace(0, len(voters) - 1, min(len(voters), 64)).astype(np.int64))
        cosang = (np.einsum("aij,bij->ab", Rv[anchors], Rv) - 1) / 2  # cos of the relative rotations
        agree = cosang > cos_tol
        group = voters[agree[int(np.argmax(agree.sum(axis=1)))]]
        if len(np.unique(si[group])) < cfg.min_inliers:
            continue
        cands.append(kabsch(model_pts[mi[group]], scene_pts[si[group]]))
        meta.append((float(v), len(group)))
    if not cands:
        return []
    cs = np.repeat(scene_pts, k, axis=0)
    cm = model_pts[np.maximum(flat, 0)]
    valid = np.flatnonzero(flat >= 0)
    T, inls = refit_batch(np.array(cands), cm[valid], cs[valid], cfg.inlier_distance)
    size = np.array([len(np.unique(valid[i] // k)) for i in inls])
    order = np.lexsort((np.arange(len(size)), -size))
    order = order[size[order] >= cfg.min_inliers]
    keep = _distinct(T, order, diameter, max_groups)
    if stats is not None:
        stats["groups"] = [{"votes": meta[i][0], "group": meta[i][1], "inliers": int(size[i])} for i in keep]
    return [Hypothesis(model_index, T[i], valid[inls[i]], meta[i][1]) for i in keep]
