"""Geometric-consistency grouping, after PCL's GeometricConsistencyGrouping (Chen and Bhanu 2007).

Correspondences are visited in order of descriptor distance. Each one not yet grouped seeds a consensus set
that grows greedily: the next candidate (again by descriptor distance) joins if it is consistent with every
member so far. Consistency is the pair test of ``grouping.pairs`` (lengths, and here also the three
point-pair angles, which PCL's distance-only test lacks). A set of at least ``cfg.min_inliers`` distinct scene
keypoints becomes a hypothesis: its members are fitted by the same robust Kabsch as RANSAC's, then every
correspondence within ``cfg.inlier_distance`` of the pose is gathered. Deterministic: no random draws.
"""
from __future__ import annotations

import numpy as np

from ..config import GroupingConfig
from .hypothesis import Hypothesis
from .pairs import ScenePairs
from .ransac import compatibility_graph, refit_batch


def consistency_groups(scene_pts: np.ndarray, cand: np.ndarray, distance: np.ndarray, model_pts: np.ndarray,
                       model_nrm: np.ndarray, pairs: ScenePairs, diameter: float, cfg: GroupingConfig,
                       model_index: int = 0, max_groups: int = 12) -> list[Hypothesis]:
    """Hypotheses from consistent groups of correspondences ``c = s * k + r``.

    scene_pts : (S, 3); cand, distance : (S, k) candidate model keypoints (-1: none) and descriptor distances;
    model_pts, model_nrm : (K, 3); pairs : scene keypoint pairs. Returns at most ``max_groups`` hypotheses,
    largest group first.
    """
    S, k = cand.shape
    M = S * k
    if M < 3:
        return []
    start, deg, nbr = compatibility_graph(pairs, cand, model_pts, model_nrm, diameter, cfg)
    cs = np.repeat(scene_pts, k, axis=0)
    cm = model_pts[np.maximum(cand.reshape(-1), 0)]
    valid = (cand.reshape(-1) >= 0) & (deg >= cfg.min_inliers - 1)
    rank = np.empty(M, np.int64)
    order = np.lexsort((np.arange(M), distance.reshape(-1)))  # descriptor distance, then index
    rank[order] = np.arange(M)
    taken = np.zeros(M, bool)
    groups: list[np.ndarray] = []
    for seed in order:
        if taken[seed] or not valid[seed]:
            continue
        allowed = np.zeros(M, bool)
        allowed[nbr[start[seed]:start[seed] + deg[seed]]] = True
        allowed &= valid & ~taken
        members = [seed]
        while allowed.any():
            idx = np.flatnonzero(allowed)
            j = int(idx[np.argmin(rank[idx])])
            members.append(j)
            row = np.zeros(M, bool)
            row[nbr[start[j]:start[j] + deg[j]]] = True
            allowed &= row
            allowed[j] = False
        members = np.array(members)
        if len(np.unique(members // k)) >= cfg.min_inliers:
            groups.append(members)
            taken[members] = True
    groups.sort(key=lambda g: -len(g))
    groups = groups[:max_groups]
    if not groups:
        return []
    from ..align import kabsch

    T0 = np.array([kabsch(cm[g], cs[g]) for g in groups])
    T, inls = refit_batch(T0, cm, cs, cfg.inlier_distance)
    return [Hypothesis(model_index, T[i], inls[i], len(groups[i])) for i in range(len(groups))
            if len(np.unique(inls[i] // k)) >= cfg.min_inliers]
