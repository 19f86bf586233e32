"""Multi-instance RANSAC over correspondences, guided by pairwise rigid consistency; deterministic.

Two correspondences are *compatible* when their scene and model point-pair features agree
(``grouping.common.compatibility_graph``): correct correspondences of one instance are all compatible with
each other. Each round draws seeds uniformly among active correspondences and completes each into a triplet
with two of its compatible partners that are also compatible with each other, fits the triplets by Kabsch,
scores each by the seed's compatible partners it explains, refits the best on all active inliers, and then
removes its correspondences and every correspondence on the surface it explains before the next round.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..align import kabsch_batch, transform
from ..errors import ConfigError
from ..graph import common_neighbours
from ..grid import GridTree, within_any
from ..matching import Candidates
from ..pairs import scene_pairs
from ..params import check_positive, param
from .common import (
    compatibility_graph,
    correspondence_points,
    distinct_poses,
    ramp,
    refit_batch,
)
from .hypothesis import Hypothesis

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

    from ..prepared_model import PreparedModel
    from ..scene import SceneKeypoints
    from . import GroupingConfig


@dataclass(frozen=True)
class RansacConfig:
    """Options of multi-instance RANSAC grouping."""

    iterations: int = param(800, "triplets drawn per cluster and instance round")
    edge_tolerance: float = param(0.006, "m; pair-length difference allowed between scene and model pairs")
    normal_tolerance_deg: float = param(20.0, "degrees; pair-angle difference allowed (point-pair features)")
    max_instances: int = param(2, "instances of one model searched per cluster")
    alternatives: int = param(4, "extra distinct poses kept per round for verification to choose from")
    rescore: int = param(20, "best triplet poses refit and re-ranked by geometric overlap with the scene "
                             "(0: off)")
    rescore_wide: int = param(100, "with rescore: this many best triplet poses are refit and ranked by overlap, "
                                   "and the wide_extra best of those beyond the first rescore are kept too")
    wide_extra: int = param(2, "extra distinct poses taken from the wider rescore pool (0: off)")
    min_normal_spread_deg: float = param(15.0, "a triplet needs a normal this far from the others (0: off)")
    guided: float = param(2.0, "seed edges are drawn with weight (1 + common compatible neighbours)^guided "
                               "(second-order compatibility: correct matches agree with each other); 0: seeds "
                               "uniform, as in plain RANSAC")

    def __post_init__(self):
        check_positive(self, "iterations", "edge_tolerance", "normal_tolerance_deg", "max_instances")
        for n in ("alternatives", "rescore", "rescore_wide", "wide_extra", "min_normal_spread_deg", "guided"):
            if getattr(self, n) < 0:
                raise ConfigError(f"RansacConfig.{n} must be >= 0, got {getattr(self, n)}")


class RansacGrouper:
    """Up to ``max_instances`` instances of one model in each scene cluster (``scene.labels``), each with up
    to ``alternatives`` other distinct poses. With the scene cloud at hand (``scene.cloud_tree``) and
    ``rescore`` > 0, the best triplet poses are re-ranked by how much of the model they lay on the scene."""

    name = "ransac"
    Config = RansacConfig
    needs_lrfs = False

    def __init__(self, cfg: "GroupingConfig"):
        self.common, self.cfg = cfg, cfg.ransac

    def group(self, scene: "SceneKeypoints", model: "PreparedModel", candidates: Candidates,
              rng: np.random.Generator, *, workers: int = 1) -> list[Hypothesis]:
        """Hypotheses for up to ``max_instances`` instances of ``model`` per scene cluster; ``rng`` draws the
        triplets."""
        m, c = model.model, self.cfg
        cand = candidates.model
        S, k = cand.shape
        out: list[Hypothesis] = []
        if S * k < 3:
            return out
        pairs = scene.cached(("pairs", m.diameter),
                             lambda: scene_pairs(scene.points, scene.normals, scene.labels, m.diameter))
        start, deg, nbr = compatibility_graph(pairs, cand, m.kp_points, m.kp_normals, diameter=m.diameter,
                                              edge_tolerance=c.edge_tolerance,
                                              normal_tolerance_deg=c.normal_tolerance_deg, workers=workers)
        cs, cm = correspondence_points(scene.points, cand, m.kp_points)
        cn = np.repeat(scene.normals, k, axis=0)
        overlap = None
        if scene.cloud_tree is not None and c.rescore > 0:
            step = -(-len(model.icp_points) // 300)  # a few hundred samples rank poses as well as all of them
            overlap = Overlap(model.icp_points[::step], model.icp_normals[::step], scene.cloud_tree,
                              0.75 * self.common.inlier_distance)
        graph = _Graph(cs, cm, cn, k, start, deg, nbr)
        if c.guided > 0:
            # second-order compatibility (SC^2, Chen et al. 2022): correspondences compatible with both ends
            graph.common, graph.keys = common_neighbours(start, deg, nbr), graph.src * len(deg) + nbr
        active = (cand.reshape(-1) >= 0) & (deg >= 2)
        labels = np.asarray(scene.labels)
        clabel = np.repeat(labels, k)
        seeds = _seed_edges(graph, clabel) if graph.common is not None else {}
        for lab in np.unique(labels[active.reshape(S, k).any(axis=1)]):
            edges = seeds.get(int(lab), np.zeros(0, np.int64))
            for _ in range(c.max_instances):
                found = self._one_instance(graph, active & (clabel == lab), m.diameter, rng, overlap, edges=edges)
                if not found:
                    break
                out += [Hypothesis(model.index, T, inl, len(inl)) for T, inl in found]
                Tb, inl = found[0]
                active[inl] = False
                # clear the surface the best pose explains (in every cluster: active is shared)
                near = within_any(scene.points, transform(Tb, m.points), 2 * self.common.inlier_distance)
                active &= ~np.repeat(near, k)
        return out

    def _one_instance(self, g: "_Graph", active: np.ndarray, diameter: float, rng: np.random.Generator,
                      overlap: "Overlap | None", *, edges: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """The best triplet poses among ``active`` correspondences, each refit on its inliers: the best first,
        then up to ``alternatives`` others that differ from every pose before them (rotation > 10 degrees or
        translation > a fifth of the diameter), for verification to choose from. Empty when none has support.
        ``edges``: the cluster's seed edges (``_seed_edges``), from which guided rounds draw (unused by plain
        RANSAC).

        Triplets are ranked by the distinct scene keypoints they explain among the seed's compatible partners;
        with an ``overlap`` score, the ``rescore`` best of them are refit and re-ranked by it."""
        c, tau, min_inl = self.cfg, self.common.inlier_distance, self.common.min_inliers
        cs, cm, k, start, deg, nbr = g.cs, g.cm, g.k, g.start, g.deg, g.nbr
        pool = np.flatnonzero(active)
        if len(pool) < 3:
            return []
        if g.common is None:  # plain RANSAC: uniform seeds, two partners each
            i0 = pool[rng.integers(0, len(pool), c.iterations)]
            d0 = deg[i0]
            j = nbr[start[i0] + (rng.random(len(i0)) * d0).astype(np.int64)]
            kk = nbr[start[i0] + (rng.random(len(i0)) * d0).astype(np.int64)]
            ok = active[j] & active[kk] & (j != kk) & (j // k != kk // k)
        else:
            i0, j, kk, ok = self._guided_triangles(g, active, rng, edges)
            if i0 is None:
                return []
        tri = np.stack([i0, j, kk], axis=1)[ok]
        if len(tri) == 0:
            return []
        # a triplet drawn again adds nothing (its pose and score are the same): keep its first draw. In a small
        # cluster most draws repeat one (800 draws, 30 distinct triplets among 100 correspondences)
        M = len(cs)
        _, first = np.unique((tri[:, 0] * M + tri[:, 1]) * M + tri[:, 2], return_index=True)
        tri = tri[np.sort(first)]
        Sx, Px = cs[tri], cm[tri]
        ds = np.linalg.norm(Sx[:, 1] - Sx[:, 2], axis=1)
        dm = np.linalg.norm(Px[:, 1] - Px[:, 2], axis=1)
        good = (np.abs(ds - dm) < c.edge_tolerance) & (ds > 0.1 * diameter)
        if c.min_normal_spread_deg > 0:
            # three points on one flat patch carry no shape: their descriptors match any flat part of the model,
            # and every such triplet is rigidly consistent. Ask for at least one normal off the others.
            Nx = g.cn[tri]
            cos = np.cos(np.radians(c.min_normal_spread_deg))
            flat = (((Nx[:, 0] * Nx[:, 1]).sum(1) > cos) & ((Nx[:, 0] * Nx[:, 2]).sum(1) > cos)
                    & ((Nx[:, 1] * Nx[:, 2]).sum(1) > cos))
            good &= ~flat
        tri, Sx, Px = tri[good], Sx[good], Px[good]
        if len(tri) == 0:
            return []
        T = kabsch_batch(Px, Sx)
        # score: distinct scene keypoints among the seed's compatible partners that the pose explains
        cnt = deg[tri[:, 0]]
        rows = np.repeat(np.arange(len(tri)), cnt)
        cols = nbr[np.repeat(start[tri[:, 0]], cnt) + ramp(cnt)]
        pred = np.einsum("nij,nj->ni", T[rows, :3, :3], cm[cols]) + T[rows, :3, 3]
        hit = active[cols] & (np.linalg.norm(pred - cs[cols], axis=1) < tau)
        n_s = len(cs) // k
        key = rows[hit] * n_s + cols[hit] // k
        if len(tri) * n_s <= 64_000_000:  # mark (triplet, scene keypoint) cells: linear, where unique sorts
            mark = np.zeros(len(tri) * n_s, bool)
            mark[key] = True
            score = np.count_nonzero(mark.reshape(len(tri), n_s), axis=1)
        else:
            score = np.bincount(np.unique(key) // n_s, minlength=len(tri))
        order = np.lexsort((np.arange(len(tri)), -score))  # best first, ties by draw order: deterministic
        order = order[score[order] + 3 >= min_inl]
        limit = max(c.rescore, c.rescore_wide) if overlap is not None else c.alternatives + 1
        lead = distinct_poses(T, order, diameter, limit)
        if len(lead) == 0:
            return []
        Tr, inls = refit_batch(T[lead], cm[pool], cs[pool], tau)
        # distinct scene keypoints among each pose's inliers: (pose, keypoint) cells counted once
        owner = np.repeat(np.arange(len(inls)), [len(i) for i in inls])
        cells = np.unique(owner * n_s + pool[np.concatenate(inls)] // k)
        n_pts = np.bincount(cells // n_s, minlength=len(inls))
        keep = np.flatnonzero(n_pts >= min_inl)
        if len(keep) == 0:
            return []
        if overlap is None or len(keep) == 1:
            keep = distinct_poses(Tr, keep, diameter, c.alternatives + 1)
            return [(Tr[i], pool[inls[i]]) for i in keep]
        lcp = overlap(Tr[keep])
        ranked = keep[np.lexsort((keep, -lcp))]  # all refit poses, most overlap first
        first = distinct_poses(Tr, ranked[ranked < c.rescore], diameter, c.alternatives + 1)
        if c.wide_extra > 0 and len(ranked) > len(first):
            # a few more from the wider pool: on near-symmetric parts the triplet counts cannot tell the
            # rotations apart, and the right one may rank below the first ``rescore``
            both = np.concatenate([first, ranked])
            first = distinct_poses(Tr, both, diameter, len(first) + c.wide_extra)
        return [(Tr[i], pool[inls[i]]) for i in first]


    def _guided_triangles(self, g: "_Graph", active: np.ndarray, rng: np.random.Generator, edges: np.ndarray):
        """``iterations`` seed edges among active correspondences, drawn with weight (1 + common compatible
        neighbours)^guided, each completed by a third correspondence compatible with both ends (the first of 4
        draws among the seed's partners that is). Returns (i0, j, kk, ok) like the plain draw."""
        start, deg, nbr, k = g.start, g.deg, g.nbr, g.k
        src = g.src
        live = edges[active[src[edges]] & active[nbr[edges]]]  # ascending, as edges are
        if len(live) == 0:
            return None, None, None, None
        w = (1.0 + g.common[live]) ** self.cfg.guided
        e = live[rng.choice(len(live), size=self.cfg.iterations, p=w / w.sum())]
        i0, j = src[e], nbr[e]
        kk = np.full(len(e), -1, np.int64)
        M = len(g.cs)
        for _ in range(4):
            cand = nbr[start[i0] + (rng.random(len(i0)) * deg[i0]).astype(np.int64)]
            key = j * M + cand
            pos = np.minimum(np.searchsorted(g.keys, key), len(g.keys) - 1)
            hit = (g.keys[pos] == key) & (kk < 0) & (cand != j)
            kk[hit] = cand[hit]
        ok = (kk >= 0) & active[np.maximum(kk, 0)] & (j // k != kk // k) & (i0 // k != kk // k)
        return i0, j, np.maximum(kk, 0), ok


@dataclass
class _Graph:
    """The correspondences of one grouping call: scene points, model points and scene normals of each (M, 3),
    candidates per scene keypoint ``k``, and the compatibility graph in CSR form."""

    cs: np.ndarray
    cm: np.ndarray
    cn: np.ndarray
    k: int
    start: np.ndarray
    deg: np.ndarray
    nbr: np.ndarray
    common: np.ndarray | None = None  # per edge (aligned with nbr): common compatible neighbours of its ends
    keys: np.ndarray | None = None  # sorted src * M + dst of every edge (nbr ascends in each row), for adjacency tests
    src: np.ndarray = field(init=False, repr=False)  # first end of every edge (aligned with nbr)

    def __post_init__(self):
        self.src = np.repeat(np.arange(len(self.deg), dtype=np.int64), self.deg)


def _seed_edges(g: _Graph, clabel: np.ndarray) -> dict:
    """{scene cluster label: ascending indices of its edges with src < dst}. Compatible correspondences lie in
    one cluster (``scene_pairs`` pairs keypoints within a cluster), so a round drawing seed edges in one cluster
    scans only these instead of the whole graph."""
    e = np.flatnonzero(g.src < g.nbr)
    if not len(e):  # no two correspondences agree (a flat scan: every FPFH alike)
        return {}
    lab = clabel[g.src[e]]
    order = np.argsort(lab, kind="stable")  # by cluster, ascending within each
    e, lab = e[order], lab[order]
    cut = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
    return {int(lab[a]): e[a:b] for a, b in zip(cut, np.r_[cut[1:], len(e)])}


@dataclass
class Overlap:
    """Geometric overlap of a posed model with the scene (the largest-common-pointset score of 4PCS):
    the number of model samples facing the camera that lie within ``distance`` of a scene point.

    points, normals : (P, 3) model samples and outward normals (model frame, m); scene_tree : KD-tree of the
    scene points (camera frame); a ``grid.GridTree`` answers on its grid.
    """

    points: np.ndarray
    normals: np.ndarray
    scene_tree: cKDTree
    distance: float

    def __call__(self, T: np.ndarray) -> np.ndarray:
        """(B,) overlap of each of B poses T (B, 4, 4) (model to camera)."""
        P = np.matmul(self.points, T[:, :3, :3].transpose(0, 2, 1)) + T[:, None, :3, 3]  # (B, P, 3)
        N = np.matmul(self.normals, T[:, :3, :3].transpose(0, 2, 1))
        front = np.einsum("bpi,bpi->bp", N, P) < 0
        if isinstance(self.scene_tree, GridTree):  # the grid stops at the first scene point within reach
            hit = self.scene_tree.within(P[front], self.distance)
        else:
            hit = np.isfinite(self.scene_tree.query(P[front], distance_upper_bound=self.distance)[0])
        return np.bincount(np.nonzero(front)[0][hit], minlength=len(T))
