"""Model-to-scan registration with no initial guess: FPFH matching, pair-consistent RANSAC, then ICP.

``register(source, target)`` returns ``T_target_source``: it maps source points into the target's frame.
Both may be meshes or point clouds (any format ``load_model`` reads); units are handled as for models.
"""
from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from .align import transform
from .blas import on_one_blas_thread
from .cloud import diameter as cloud_diameter
from .cloud import outward_normals, voxel_downsample
from .config import PipelineConfig, RefineConfig
from .errors import ConfigError, InputError
from .features import fpfh
from .grid import GridTree
from .grouping import GROUPERS, make_grouper
from .grouping.hypothesis import Hypothesis
from .io.models import Geometry, as_geometry
from .keypoints import select_keypoints
from .lrf import shot_lrf
from .matching import match_features
from .model import ObjectModel
from .params import check_positive
from .prepared_model import PreparedModel
from .refine import RegistrationResult, icp, icp_many
from .scene import SceneKeypoints

# A model on one of its partial scans explains all of the scan (coverage >= 0.97 on the bunny) but half of the
# model (fitness 0.51-0.54); two scans explain each other (0.92 / 0.97); a box on a ball, or the bunny on a
# ball, reach at most 0.32. Below this on both sides a registration is reported as doubtful.
LOW_OVERLAP = 0.5
# ICP iterations each alternative hypothesis gets before the best one is refined further
SHORT_ICP = 10
# source samples the short ICPs move (evenly taken; they are then ranked on all samples): on the 33 pairs of
# scripts/bench_register.py as accurate as all ~1,000-1,400, and the short ICPs take a third of the time
SHORT_POINTS = 400
# each hypothesis also gets a short ICP that first reaches this many voxels (with a kernel of half of it), then the
# usual 3: at low overlap the feature matches can agree best on a pose 3 voxels off. On the dragon's scans 72
# degrees apart (264 -> 336) the best hypotheses lie 17-18 mm off (3 voxels) holding more matches than the truth
# (71 against 54), and the usual reach stops 19 mm off; from the wider one the pair registers (40 of the 48 pairs
# 24-72 degrees apart against 39, none lost, 1.1x the time). Both results compete on fitness. 0: no wide ICP.
WIDE_REACH = 6.0


class RegistrationWarning(UserWarning):
    """A registration that explains little of either input (``fitness`` and ``coverage`` both < 0.5)."""


@dataclass(frozen=True)
class RegisterConfig:
    """voxel: sampling of both inputs (m; None: 1/40 of the source's diameter); the rest scale with it.
    k: FPFH candidates per target keypoint (None: 1 for RANSAC, and 3 if that finds no consistent alignment or
    a doubtful one, with fitness and coverage both under ``LOW_OVERLAP``; 3 for the other groupers). On the 33
    pairs of ``python scripts/bench_register.py``, RANSAC registered 30 within 2 mm at k = 1 as at k = 3 (and
    faster: 0.13 s a pair instead of 0.20 when this was chosen); geometric consistency drops to 27. With the retry
    of doubtful results, 32.
    iterations: RANSAC draws (guided by second-order consistency). 300, 500, 700 and 1000 draws all register 31-32
    of those 33 pairs for seeds 0-3; 500 is 9 % faster than 1000 in all."""

    voxel: float | None = None
    grouping: str = "ransac"
    k: int | None = None
    iterations: int = 500
    alternatives: int = 5
    icp_iterations: int = 50
    seed: int = 0

    def __post_init__(self):
        if self.voxel is not None and not 0 < self.voxel < np.inf:
            raise ConfigError(f"RegisterConfig.voxel must be > 0 (m) or None, got {self.voxel!r}")
        if self.k is not None and not self.k >= 1:
            raise ConfigError(f"RegisterConfig.k must be >= 1 or None, got {self.k!r}")
        check_positive(self, "iterations", "alternatives")
        if not self.icp_iterations >= 0:
            raise ConfigError(f"RegisterConfig.icp_iterations must be >= 0, got {self.icp_iterations!r}")


@dataclass
class Registration:
    """The alignment and how it was found. ``T_target_source`` (4, 4) maps source points into the target;
    ``fitness``: share of the source samples on the target after alignment; ``coverage``: share of the target
    samples on the source (both within 1.5 voxel); ``rmse_m``: point-to-plane residual of the fitting part."""

    T_target_source: np.ndarray
    fitness: float
    rmse_m: float
    n_inliers: int
    candidates: int
    timing_s: dict = field(default_factory=dict)
    coverage: float = 0.0


def _prepared(points: np.ndarray, normals: np.ndarray | None, voxel: float):
    p, n, _ = voxel_downsample(points, voxel, normals, representatives=False)
    if n is None or not (np.linalg.norm(n, axis=1) > 0.5).all():
        n = outward_normals(p, 2.5 * voxel, 30)
    return p, n


@on_one_blas_thread
def register(source, target, config: RegisterConfig | None = None, *, units="auto") -> Registration:
    """Align ``source`` to ``target`` globally, then refine by ICP. Each is a mesh or cloud file, an (N, 3)
    array of points, an open3d ``PointCloud`` / ``TriangleMesh`` or a trimesh object (``io.models.as_geometry``).
    BLAS runs on one thread meanwhile (``pcdet.blas``): a second thread only slows its small products.

    >>> r = register("bun_zipper_res3.ply", "bun045.ply")
    >>> r.T_target_source  # (4, 4): source points into the target's frame
    """
    import time

    cfg = config or RegisterConfig()
    if cfg.grouping not in GROUPERS:
        raise InputError(f"grouping {cfg.grouping!r} is not available; use one of {', '.join(map(repr, GROUPERS))}")
    t0 = time.perf_counter()
    src, tgt = as_geometry(source, units, name="source"), as_geometry(target, units, name="target")
    s_pts, s_nrm = _surface(src)
    t_pts, t_nrm = _surface(tgt)
    # the hull of every n-th point of a dense scan (scan lines are even) is within a sampling step of the whole's
    diameter = cloud_diameter(s_pts[::-(-len(s_pts) // 10000)])
    voxel = cfg.voxel or diameter / 40.0
    sp, sn = _prepared(s_pts, s_nrm, voxel)
    tp, tn = _prepared(t_pts, t_nrm, voxel)
    if len(sp) < 10 or len(tp) < 10:
        raise InputError(f"too few points after sampling at {voxel:.4f} m (source {len(sp)}, target {len(tp)})")
    # RANSAC without overlap re-ranking and without the flat-triplet test: one instance, of a whole scan
    pc = PipelineConfig().replace(
        keypoints={"spacing": 2 * voxel},
        features={"radius": 5 * voxel},
        matching={"k": cfg.k or (1 if cfg.grouping == "ransac" else 3)},
        grouping={"method": cfg.grouping, "inlier_distance": 2.5 * voxel, "min_inliers": 5,
                  "ransac": {"iterations": cfg.iterations, "edge_tolerance": 1.5 * voxel, "max_instances": 1,
                             "alternatives": cfg.alternatives, "rescore": 0, "min_normal_spread_deg": 0.0},
                  "gc": {"edge_tolerance": 1.5 * voxel},
                  "hough": {"bin": 10 * voxel, "rotation_tol_deg": 35.0}},
    )
    t1 = time.perf_counter()
    skp = select_keypoints(sp, pc.keypoints)
    tkp = select_keypoints(tp, pc.keypoints)
    sf = fpfh(sp, sn, skp, pc.features)
    tf = fpfh(tp, tn, tkp, pc.features)
    grouper = make_grouper(pc.grouping)
    lrf = (lambda pts, kp: shot_lrf(pts, pts[kp], pc.features.radius)[0]) if grouper.needs_lrfs else None
    path = str(source) if isinstance(source, (str, Path)) else ""
    model = ObjectModel("source", 0, path, sp, sn, sp[skp], sn[skp], sf,
                        lrf(sp, skp) if lrf else np.full((len(skp), 3, 3), np.nan), diameter)
    tree = GridTree(tp)  # ICP and the fitness search within a few voxels: on a grid
    scene = SceneKeypoints(tp[tkp], tn[tkp], lrfs=lrf(tp, tkp) if lrf else None, cloud_tree=tree)
    prepared = PreparedModel(model, 0, sp, sn, sp.mean(axis=0), cKDTree(sf))
    rc = RefineConfig(iterations=cfg.icp_iterations, max_distance=3 * voxel, kernel=1.5 * voxel)
    # a step this small is far below the sampling: stop there (0.02-0.04 mm on the dragon; the bench's errors move by
    # at most 0.02 mm against a tolerance 4 times tighter, and the polishing ICPs take half the iterations)
    tol = (4e-4, 4e-3 * voxel)

    def hypotheses(k: int) -> list[Hypothesis]:
        cand = match_features(tf, sf, dataclasses.replace(pc.matching, k=k),
                              model_tree=prepared.descriptor_tree)  # the target looks up the source
        return grouper.group(scene, prepared, cand, np.random.default_rng(cfg.seed))

    def on_target(moved: np.ndarray) -> float:  # share of the moved source samples within 1.5 voxel of the target
        return float(np.isfinite(tree.query(moved, distance_upper_bound=1.5 * voxel)[0]).mean())

    def refined(hyps: list[Hypothesis]) -> tuple[RegistrationResult, Hypothesis, float, float]:
        """The best hypothesis refined, the hypothesis, and its fitness and coverage (both at 1.5 voxel)."""
        # every hypothesis gets a short ICP, and only the best of them the rest of the iterations. The best is the
        # one with most of the source on the target within 1.5 voxel (the fitness reported), not within the ICP's
        # own 3 voxels: at that looser reach a pose slid along a scan of a curved object can hold as many points
        best, best_h, best_key = None, None, None
        short = dataclasses.replace(rc, iterations=min(SHORT_ICP, rc.iterations))
        few = sp[::-(-len(sp) // SHORT_POINTS)]
        # each hypothesis's T_scene_model is a T_target_source; the short ICPs run side by side (icp_many)
        starts = [h.T_scene_model for h in hyps]
        if WIDE_REACH:
            wide = dataclasses.replace(short, max_distance=WIDE_REACH * voxel, kernel=WIDE_REACH / 2 * voxel)
            starts += [r.T_target_source for r in icp_many([few] * len(hyps), tp, tn, starts, wide,
                                                           target_tree=tree, tolerance=tol)]
            hyps = hyps + hyps
        shorts = icp_many([few] * len(starts), tp, tn, starts, short, target_tree=tree, tolerance=tol)
        for h, r in zip(hyps, shorts):
            key = (on_target(transform(r.T_target_source, sp)), -r.rmse_m)
            if best_key is None or key > best_key:
                best, best_h, best_key = r, h, key
        if not best.converged and rc.iterations > SHORT_ICP:
            best = icp(sp, tp, tn, best.T_target_source,
                       dataclasses.replace(rc, iterations=rc.iterations - SHORT_ICP), target_tree=tree, tolerance=tol)
        # final polish at tighter distances: the last at half a voxel, so that the rim of the overlap (points
        # whose partner the other scan never saw) no longer pulls (Open3D's recipe ends at 0.4 voxel)
        for dist, kern in ((1.5 * voxel, voxel), (0.5 * voxel, 0.5 * voxel)):
            rc2 = RefineConfig(iterations=cfg.icp_iterations, max_distance=dist, kernel=kern)
            best = icp(sp, tp, tn, best.T_target_source, rc2, target_tree=tree, tolerance=tol)
        # both shares at 1.5 voxel, as documented (the last ICP round's own fitness counts only half a voxel)
        moved = transform(best.T_target_source, sp)
        coverage = float(np.isfinite(cKDTree(moved).query(tp, distance_upper_bound=1.5 * voxel)[0]).mean())
        return best, best_h, on_target(moved), coverage

    hyps = hypotheses(pc.matching.k)
    more = cfg.k is None and pc.matching.k < 3  # one candidate each may be too few: three then
    if not hyps and more:
        hyps, more = hypotheses(3), False
    t2 = time.perf_counter()
    if not hyps:
        raise InputError("no consistent alignment found: do the inputs overlap, and are they in the same units?")
    best, best_h, fitness, coverage = refined(hyps)
    t3 = time.perf_counter()
    timing = {"load": t1 - t0, "global": t2 - t1, "icp": t3 - t2}
    if more and max(fitness, coverage) < LOW_OVERLAP:
        # a doubtful alignment: with three candidates per keypoint the overlap may show more correct matches (on
        # scans 48 degrees apart the one candidate left too few); the larger fitness is kept
        again = hypotheses(3)
        if again:
            second = refined(again)
            if second[2] > fitness:
                hyps, (best, best_h, fitness, coverage) = again, second
        timing["retry"] = time.perf_counter() - t3
    if max(fitness, coverage) < LOW_OVERLAP:
        warnings.warn(f"after alignment only {fitness:.0%} of the source lies on the target and {coverage:.0%} "
                      f"of the target on the source (within {1.5 * voxel * 1000:.1f} mm): the inputs may not "
                      "overlap, or may not be the same object", RegistrationWarning, stacklevel=2)
    return Registration(best.T_target_source, fitness, best.rmse_m, best_h.n_inliers, len(hyps), timing, coverage)



def _surface(g: Geometry) -> tuple[np.ndarray, np.ndarray | None]:
    """Dense surface points (and outward normals for meshes): 60k area-uniform samples of a mesh, or the
    cloud's points (and its normals, if the file has them)."""
    if g.faces is None:
        return g.vertices, g.normals
    import trimesh

    mesh = trimesh.Trimesh(g.vertices, g.faces, process=False)
    pts, fidx = trimesh.sample.sample_surface(mesh, 60000, seed=0)
    return np.asarray(pts), np.asarray(mesh.face_normals)[fidx]
