"""Model-to-scan registration with no initial guess: FPFH matching, pair-consistent RANSAC, then ICP.

``register(source, target)`` returns ``T_target_source``: it maps source points into the target's frame.
Both may be meshes or point clouds (any format ``load_model`` reads); units are handled as for models.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from .cloud import voxel_downsample
from .config import PipelineConfig, RefineConfig
from .errors import InputError
from .features import fpfh
from .grouping.consistency import consistency_groups
from .grouping.hough import hough_groups
from .grouping.pairs import scene_pairs
from .grouping.ransac import ransac_instances
from .keypoints import select_keypoints
from .lrf import shot_lrf
from .matching import match_features
from .model import Geometry, _diameter, _outward_normals, load_geometry
from .refine import RegistrationResult, icp


@dataclass(frozen=True)
class RegisterConfig:
    """voxel: sampling of both inputs (m; None: 1/40 of the source's diameter); the rest scale with it."""

    voxel: float | None = None
    grouping: str = "ransac"
    k: int = 3
    iterations: int = 4000
    alternatives: int = 5
    icp_iterations: int = 50
    seed: int = 0


@dataclass
class Registration:
    """The alignment and how it was found. ``T_target_source`` (4, 4) maps source points into the target."""

    T_target_source: np.ndarray
    fitness: float
    rmse_m: float
    n_inliers: int
    candidates: int
    timing_s: dict = field(default_factory=dict)


def _prepared(points: np.ndarray, normals: np.ndarray | None, voxel: float):
    p, n, _ = voxel_downsample(points, voxel, normals)
    if n is None or not (np.linalg.norm(n, axis=1) > 0.5).all():
        n = _outward_normals(p, 2.5 * voxel, 30)
    return p, n


def register(source, target, config: RegisterConfig | None = None, units="auto") -> Registration:
    """Align ``source`` to ``target`` (model or cloud file paths) globally, then refine by ICP."""
    import time

    cfg = config or RegisterConfig()
    t0 = time.perf_counter()
    src, tgt = load_geometry(source, units), load_geometry(target, units)
    s_pts, s_nrm = _surface(src)
    t_pts, t_nrm = _surface(tgt)
    diameter = _diameter(s_pts)
    voxel = cfg.voxel or diameter / 40.0
    sp, sn = _prepared(s_pts, s_nrm, voxel)
    tp, tn = _prepared(t_pts, t_nrm, voxel)
    if len(sp) < 10 or len(tp) < 10:
        raise InputError(f"too few points after sampling at {voxel:.4f} m (source {len(sp)}, target {len(tp)})")
    pc = PipelineConfig().replace(
        keypoints={"spacing": 2 * voxel},
        features={"radius": 5 * voxel},
        matching={"k": cfg.k},
        grouping={"iterations": cfg.iterations, "inlier_distance": 2.5 * voxel, "edge_tolerance": 1.5 * voxel,
                  "min_inliers": 5, "max_instances": 1, "alternatives": cfg.alternatives},
    )
    t1 = time.perf_counter()
    skp = select_keypoints(sp, pc.keypoints)
    tkp = select_keypoints(tp, pc.keypoints)
    sf = fpfh(sp, sn, skp, pc.features)
    tf = fpfh(tp, tn, tkp, pc.features)
    cand = match_features(tf, sf, pc.matching)  # target keypoints look up source descriptors
    pairs = scene_pairs(tp[tkp], tn[tkp], np.zeros(len(tkp), np.int64), diameter)
    if cfg.grouping == "gc":
        hyps = consistency_groups(tp[tkp], cand.model, cand.distance, sp[skp], sn[skp], pairs, diameter,
                                  pc.grouping)
    elif cfg.grouping == "ransac":
        hyps = ransac_instances(tp[tkp], cand.model, sp[skp], sn[skp], pairs, diameter, pc.grouping,
                                np.random.default_rng(cfg.seed))
    elif cfg.grouping == "hough":
        frames = []
        for pts, kp in ((tp, tkp), (sp, skp)):
            F, ok = shot_lrf(pts, pts[kp], pc.features.radius)
            F[~ok] = np.nan
            frames.append(F)
        gcfg = dataclasses.replace(pc.grouping, hough_bin=10 * voxel, hough_rotation_tol_deg=35.0)
        hyps = hough_groups(tp[tkp], frames[0], cand.model, sp[skp], frames[1], sp.mean(axis=0), diameter, gcfg)
    else:
        raise InputError(f"grouping {cfg.grouping!r} is not available; use 'ransac', 'gc' or 'hough'")
    t2 = time.perf_counter()
    if not hyps:
        raise InputError("no consistent alignment found: do the inputs overlap, and are they in the same units?")
    tree = cKDTree(tp)
    rc = RefineConfig(iterations=cfg.icp_iterations, max_distance=3 * voxel, kernel=1.5 * voxel)
    best: RegistrationResult | None = None
    best_h = None
    for h in hyps:
        r = icp(sp, tp, tn, h.T_cam_model, rc, target_tree=tree)
        if best is None or (r.fitness, -r.rmse_m) > (best.fitness, -best.rmse_m):
            best, best_h = r, h
    # final polish at a tighter distance
    rc2 = RefineConfig(iterations=cfg.icp_iterations, max_distance=1.5 * voxel, kernel=voxel)
    best = icp(sp, tp, tn, best.T_target_source, rc2, target_tree=tree)
    t3 = time.perf_counter()
    return Registration(best.T_target_source, best.fitness, best.rmse_m, best_h.n_inliers, len(hyps),
                        {"load": t1 - t0, "global": t2 - t1, "icp": t3 - t2})


def _surface(g: Geometry) -> tuple[np.ndarray, np.ndarray | None]:
    """Dense surface points (and outward normals for meshes): 60k area-uniform samples of a mesh, or the
    cloud's points (and its normals, if the file has them)."""
    if g.faces is None:
        return g.vertices, g.normals
    import trimesh

    mesh = trimesh.Trimesh(g.vertices, g.faces, process=False)
    pts, fidx = trimesh.sample.sample_surface(mesh, 60000, seed=0)
    return np.asarray(pts), np.asarray(mesh.face_normals)[fidx]
