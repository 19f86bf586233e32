"""The detector: the only place that knows the order of the stages."""
from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from .cloud import voxel_downsample
from .config import PipelineConfig
from .features import fpfh
from .frame import Frame
from .global_verify import candidate_terms, select
from .grouping import Hypothesis, ransac_instances
from .grouping.consistency import consistency_groups
from .grouping.hough import hough_groups
from .lrf import shot_lrf
from .grouping.ransac import Overlap
from .grouping.pairs import scene_pairs
from .keypoints import select_keypoints
from .matching import match_features
from .model import ModelLibrary
from .preprocess import preprocess
from .refine import icp
from .verify import Verification, resolve_conflicts, verify


@dataclass
class Detection:
    """One found object instance. ``T_cam_model`` (4, 4) maps model points (m) into the camera frame (for
    point-cloud inputs: into the cloud file's frame). ``group_size``: correspondences in the group the grouper
    proposed it from; ``n_inliers``: correspondences that agree with it after the robust refit."""

    model: str
    obj_id: int
    score: float
    T_cam_model: np.ndarray
    n_inliers: int
    fitness: float
    rmse_m: float
    visible_fraction: float
    group_size: int = 0

    def to_dict(self) -> dict:
        return {"model": self.model, "obj_id": self.obj_id, "score": round(float(self.score), 6),
                "T_cam_model": np.round(self.T_cam_model, 9).tolist(), "n_inliers": int(self.n_inliers),
                "group_size": int(self.group_size),
                "fitness": round(float(self.fitness), 6), "rmse_m": round(float(self.rmse_m), 9),
                "visible_fraction": round(float(self.visible_fraction), 6)}


@dataclass
class DetectionResult:
    """Detections (best score first), the time each stage took (s), and counts for diagnosis."""

    detections: list[Detection]
    timing_s: dict[str, float] = field(default_factory=dict)
    stats: dict[str, int] = field(default_factory=dict)


class _Timer:
    def __init__(self):
        self.t: dict[str, float] = {}

    @contextmanager
    def __call__(self, name):
        t0 = time.perf_counter()
        yield
        self.t[name] = self.t.get(name, 0.0) + time.perf_counter() - t0


class Detector:
    """Find the library's objects in frames.

    >>> det = Detector(ModelLibrary.from_folder("models"), load_pipeline("default"))
    >>> result = det.detect(Frame.from_depth_png("depth.png", "camera.json"))
    """

    def __init__(self, library: ModelLibrary, config: PipelineConfig | None = None, workers: int | None = None):
        """``workers``: threads for the per-model and per-hypothesis work (default: the machine's cores). Every
        task is independent and has its own generator, so the output is the same for any number."""
        self.library = library
        self.config = config or PipelineConfig()
        self.workers = max(1, workers or os.cpu_count() or 1)
        self._pool = ThreadPoolExecutor(self.workers) if self.workers > 1 else None
        self._trees = [cKDTree(m.features) for m in library]
        self._reference = [(m.points.max(0) + m.points.min(0)) / 2 for m in library]  # Hough vote target
        # per model: (points (P, 3), normals (P, 3)) on a grid of twice the scene voxel, what ICP moves (far
        # fewer than verification needs; the shape is kept)
        self.icp_points: list[tuple[np.ndarray, np.ndarray]] = []
        for m in library:
            p, n, _ = voxel_downsample(m.points, 2 * self.config.preprocess.voxel, m.normals, representatives=False)
            self.icp_points.append((p, n))

    def _map(self, fn, items) -> list:
        """``[fn(x) for x in items]``, on the thread pool when there is one; results keep the input order."""
        items = list(items)
        if self._pool is None or len(items) < 2:
            return [fn(x) for x in items]
        return list(self._pool.map(fn, items))

    def _hypotheses(self, scene, scene_tree, kp: np.ndarray, feats: np.ndarray, models: list[int], tm: "_Timer"
                    ) -> list[Hypothesis]:
        """Match scene keypoints ``kp`` (their FPFH ``feats``) against each model in ``models`` and group the
        candidates into pose hypotheses, one model per thread."""
        cfg = self.config
        hyps: list[Hypothesis] = []
        seeds = np.random.SeedSequence(cfg.seed).spawn(len(self.library))
        kpts, knrm, klab = scene.points[kp], scene.normals[kp], scene.labels[kp]
        scene_lrf = None
        if cfg.grouping.method == "hough":
            with tm("lrf"):
                scene_lrf, ok = shot_lrf(scene.points, kpts, cfg.features.lrf_support, scene_tree)
                scene_lrf[~ok] = np.nan
        with tm("matching"):
            cands = {i: match_features(feats, self.library[i].features, cfg.matching, self._trees[i],
                                       self.workers) for i in models}
        with tm("grouping"):
            # large models need no denser grid of scene points than diameter / grid_per_diameter
            pair_cache: dict[tuple[float, float], tuple] = {}
            keys = {}
            for i in models:
                m = self.library[i]
                step = max(cfg.keypoints.spacing, m.diameter / cfg.grouping.grid_per_diameter)
                keys[i] = (round(step, 4), round(m.diameter, 3))
                if keys[i] not in pair_cache:
                    sub = np.arange(len(kp)) if step <= cfg.keypoints.spacing * 1.05 else \
                        np.sort(voxel_downsample(kpts, step)[2])
                    pair_cache[keys[i]] = (sub, scene_pairs(kpts[sub], knrm[sub], klab[sub], m.diameter))

            def group(i):
                m = self.library[i]
                sub, pairs = pair_cache[keys[i]]
                rng = np.random.default_rng(seeds[i])  # one generator per model: order and threads do not matter
                if cfg.grouping.method == "hough":
                    return hough_groups(kpts[sub], scene_lrf[sub], cands[i].model[sub], m.kp_points, m.kp_lrfs,
                                        self._reference[i], m.diameter, cfg.grouping, i)
                if cfg.grouping.method == "gc":
                    return consistency_groups(kpts[sub], cands[i].model[sub], cands[i].distance[sub], m.kp_points,
                                              m.kp_normals, pairs, m.diameter, cfg.grouping, i)
                overlap = Overlap(*self.icp_points[i], scene_tree, 0.75 * cfg.grouping.inlier_distance)
                return ransac_instances(kpts[sub], cands[i].model[sub], m.kp_points, m.kp_normals, pairs,
                                        m.diameter, cfg.grouping, rng, klab[sub], i, m.points, overlap, knrm[sub])

            for h in self._map(group, models):
                hyps += h
        return hyps

    def _select_global(self, scene, scene_tree, order, hyps, regs, vers) -> list[int]:
        """The subset of ``order`` (indices of accepted hypotheses) that best explains the scene
        (``global_verify``), best verification score first."""
        v = self.config.verify
        pts = []
        for j in order:
            T = regs[j].T_target_source
            pts.append(self.library[hyps[j].model_index].points @ T[:3, :3].T + T[:3, 3])
        ratio = np.array([vers[j].n_violations / max(vers[j].n_supported, 1) for j in order])
        terms = candidate_terms(scene.points, scene_tree, pts, ratio, v.explain_radius, v.clutter_radius)
        chosen, _ = select(terms, v.duplicate_weight, v.clutter_weight, v.violation_weight)
        return [order[i] for i in sorted(chosen)]

    def detect(self, frame: Frame, targets: dict[int, int] | None = None) -> DetectionResult:
        """Detect objects in ``frame``.

        targets : optional ``{obj_id: count}`` (BOP localisation): only those objects are searched and the
            ``count`` best-scoring verified instances of each are kept, without the score threshold.
        """
        cfg = self.config
        tm = _Timer()
        with tm("preprocess"):
            scene = preprocess(frame, cfg.preprocess, cfg.seed)
        stats = {"scene_points": len(scene.points)}
        with tm("keypoints"):
            kp = select_keypoints(scene.points, cfg.keypoints)
        with tm("features"):
            feats = fpfh(scene.points, scene.normals, kp, cfg.features)
        stats["scene_keypoints"] = len(kp)
        models = [i for i, m in enumerate(self.library) if targets is None or m.obj_id in targets]
        scene_tree = cKDTree(scene.points) if len(scene.points) else None
        hyps = self._hypotheses(scene, scene_tree, kp, feats, models, tm)
        stats["hypotheses"] = len(hyps)
        if len(hyps) == 0 or len(scene.points) == 0:
            stats["refined"] = stats["detections"] = 0
            return DetectionResult([], tm.t, stats)
        with tm("verify"):
            # cheap first look at the raw poses: only plausible ones are worth an ICP
            pre = self._map(lambda h: verify(self.library[h.model_index], h.T_cam_model, frame.depth, frame.camera,
                                             cfg.verify, cfg.preprocess.voxel, scene.plane, stride=2), hyps)
        # ICP for the best few raw hypotheses of each model only
        keep = [j for j, v in enumerate(pre) if v.score >= cfg.verify.prefilter and v.n_supported > 0]
        per_model: dict[int, list[int]] = {}
        for j in sorted(keep, key=lambda j: (-pre[j].score, j)):
            per_model.setdefault(hyps[j].model_index, []).append(j)
        keep = sorted(j for js in per_model.values() for j in js[: cfg.refine.max_per_model])
        hyps = [hyps[j] for j in keep]
        stats["refined"] = len(hyps)
        with tm("refine"):
            regs = self._map(lambda h: icp(self.icp_points[h.model_index][0], scene.points, scene.normals,
                                           h.T_cam_model, cfg.refine, self.icp_points[h.model_index][1], scene_tree,
                                           np.zeros(3)), hyps)
        with tm("verify"):
            vers: list[Verification] = self._map(
                lambda hr: verify(self.library[hr[0].model_index], hr[1].T_target_source, frame.depth, frame.camera,
                                  cfg.verify, cfg.preprocess.voxel, scene.plane), list(zip(hyps, regs)))
            order = sorted(range(len(hyps)), key=lambda j: (-vers[j].score, j))
            if targets is None:
                order = [j for j in order if vers[j].accepted(cfg.verify)]
            else:
                order = [j for j in order if vers[j].n_supported > 0]
            if targets is None and cfg.verify.selection == "global":
                kept = self._select_global(scene, scene_tree, order, hyps, regs, vers)
            else:
                kept = resolve_conflicts(order, [v.support for v in vers], cfg.verify.conflict_overlap,
                                         frame.depth.size)
            if targets is not None:
                left = dict(targets)
                chosen = []
                for j in kept:
                    oid = self.library[hyps[j].model_index].obj_id
                    if left.get(oid, 0) > 0:
                        chosen.append(j)
                        left[oid] -= 1
                kept = chosen
        dets = []
        for j in kept:
            m = self.library[hyps[j].model_index]
            r, v = regs[j], vers[j]
            dets.append(Detection(m.name, m.obj_id, v.score, frame.T_input_cam @ r.T_target_source,
                                  hyps[j].n_inliers, r.fitness, r.rmse_m, v.visible_fraction, hyps[j].group))
        stats["detections"] = len(dets)
        return DetectionResult(dets, tm.t, stats)
