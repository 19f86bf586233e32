"""Geometric-consistency grouping, after PCL's GeometricConsistencyGrouping (Chen and Bhanu 2007).

Correspondences are visited in order of descriptor distance. Each one not yet grouped seeds a consensus set
that grows greedily: the next candidate (again by descriptor distance) joins if it is consistent with every
member so far. Consistency is the pair test of ``grouping.common.compatibility_graph`` (lengths, and here also
the three point-pair angles, which PCL's distance-only test lacks). A set of at least ``min_inliers`` distinct
scene keypoints becomes a hypothesis: its members are fitted by the same robust Kabsch as RANSAC's, then every
correspondence within ``inlier_distance`` of the pose is gathered. Deterministic: no random draws.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..align import kabsch
from ..matching import Candidates
from ..pairs import scene_pairs
from ..params import check_positive, param
from .common import compatibility_graph, correspondence_points, refit_batch
from .hypothesis import Hypothesis

if TYPE_CHECKING:
    from ..prepared_model import PreparedModel
    from ..scene import SceneKeypoints
    from . import GroupingConfig


@dataclass(frozen=True)
class ConsistencyConfig:
    """Options of geometric-consistency grouping."""

    edge_tolerance: float = param(0.006, "m; pair-length difference allowed between scene and model pairs")
    normal_tolerance_deg: float = param(20.0, "degrees; pair-angle difference allowed (point-pair features)")
    max_groups: int = param(12, "largest consistent groups kept per model")

    def __post_init__(self):
        check_positive(self, "edge_tolerance", "normal_tolerance_deg", "max_groups")


class ConsistencyGrouper:
    """At most ``max_groups`` hypotheses per model, largest consistent group first."""

    name = "gc"
    Config = ConsistencyConfig
    needs_lrfs = False

    def __init__(self, cfg: "GroupingConfig"):
        self.common, self.cfg = cfg, cfg.gc

    def group(self, scene: "SceneKeypoints", model: "PreparedModel", candidates: Candidates,
              rng: np.random.Generator, *, workers: int = 1) -> list[Hypothesis]:
        """Hypotheses from the consistent groups of ``candidates`` (see the module docstring)."""
        m, c, min_inl = model.model, self.cfg, self.common.min_inliers
        cand = candidates.model
        S, k = cand.shape
        M = S * k
        if M < 3:
            return []
        pairs = scene.cached(("pairs", m.diameter),
                             lambda: scene_pairs(scene.points, scene.normals, scene.labels, m.diameter))
        start, deg, nbr = compatibility_graph(pairs, cand, m.kp_points, m.kp_normals, diameter=m.diameter,
                                              edge_tolerance=c.edge_tolerance,
                                              normal_tolerance_deg=c.normal_tolerance_deg, workers=workers)
        cs, cm = correspondence_points(scene.points, cand, m.kp_points)
        valid = (cand.reshape(-1) >= 0) & (deg >= min_inl - 1)
        rank = np.empty(M, np.int64)
        order = np.lexsort((np.arange(M), candidates.distance.reshape(-1)))  # descriptor distance, then index
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
            if len(np.unique(members // k)) >= min_inl:
                groups.append(members)
                taken[members] = True
        groups.sort(key=lambda g: -len(g))
        groups = groups[:c.max_groups]
        if not groups:
            return []
        T0 = np.array([kabsch(cm[g], cs[g]) for g in groups])
        T, inls = refit_batch(T0, cm, cs, self.common.inlier_distance)
        return [Hypothesis(model.index, T[i], inls[i], len(groups[i])) for i in range(len(groups))
                if len(np.unique(inls[i] // k)) >= min_inl]
