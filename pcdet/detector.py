"""The detector: the only place that knows the order of the stages.

preprocess -> keypoints -> features (a ``Scene``) -> matching and grouping per model (a ``Grouper`` from the
registry, on ``PreparedModel`` s; once per family of look-alikes) -> a quick look at each raw pose -> a short
coarse ICP for the best raw poses of each grouped model -> each model (each member of a family, from its
representative's coarse poses) refined by ICP at its best few -> verification -> one size per spot among
look-alikes -> selection (global or by threshold).
"""
from __future__ import annotations

import os
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from .align import transform
from .blas import on_one_blas_thread
from .cloud import estimate_normals, voxel_downsample
from .colour import chromaticity, colour_within, image_colours
from .config import PipelineConfig
from .features import fpfh
from .frame import Frame
from .global_verify import candidate_terms, same_object_conflicts, select
from .grouping import Hypothesis, make_grouper
from .grouping.common import distinct_poses, distinct_surfaces
from .keypoints import select_keypoints, voxel_keypoint_levels
from .library import ModelLibrary
from .look_alikes import Family, look_alike_families, transfer
from .matching import Candidates, LibraryIndex, match_bounded, match_features, match_library
from .prepared_model import PreparedModel
from .preprocess import preprocess
from .refine import RefineConfig, RegistrationResult, icp, icp_many, scale_fit
from .scene import Scene, SceneKeypoints
from .verify import Verification, bbox_pixels, continuing_surface, resolve_conflicts, size_fit, verify_poses


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

    def __repr__(self) -> str:
        x, y, z = self.T_cam_model[:3, 3]
        return (f"Detection({self.model!r}, obj_id={self.obj_id}, score={self.score:.3f}, "
                f"at ({x:.3f}, {y:.3f}, {z:.3f}) m)")

    def to_dict(self) -> dict:
        """The detection as the detections JSON stores it (pose rounded to 1e-9)."""
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

    def __repr__(self) -> str:
        found = ", ".join(f"{d.model} {d.score:.2f}" for d in self.detections[:5])
        more = f", ... {len(self.detections) - 5} more" if len(self.detections) > 5 else ""
        return (f"DetectionResult({len(self.detections)} detection(s){': ' + found if found else ''}{more}; "
                f"{sum(self.timing_s.values()):.2f} s)")


@dataclass
class Trace:
    """What one ``detect`` call went through, for diagnosis (``Detector.detect(..., trace=Trace())`` fills it):
    the scene; per grouped model's index (a look-alike has no entry: it uses its representative's, ``family_of``) the
    candidate table (all scene keypoints; the rows a model does not group hold the coarser search's candidates,
    ``matching.screen_eps``), the scene keypoints on the model's grid (``grid``: indices into the
    scene's keypoints, before ``grouping.max_keypoints``) and those it grouped (``grouped``: the grid's keypoints
    with a candidate, within ``grouping.max_keypoints``); every raw hypothesis
    and the quick first-look verification of each; which got the coarse ICP and which were refined (indices
    into ``hypotheses``), their ICP results and verifications; the indices into ``refined`` that passed the
    per-pose checks, in score order, and those finally kept. With global selection, ``selection`` holds its
    inputs: ``(terms, conflicts)`` for the accepted poses in ``accepted``'s order (``global_verify.select``
    on them with the config's weights gives ``kept``)."""

    scene: Scene | None = None
    candidates: dict = field(default_factory=dict)
    grid: dict = field(default_factory=dict)
    grouped: dict = field(default_factory=dict)
    hypotheses: list = field(default_factory=list)
    first_look: list = field(default_factory=list)
    coarse: list = field(default_factory=list)
    refined: list = field(default_factory=list)
    registrations: list = field(default_factory=list)
    verifications: list = field(default_factory=list)
    accepted: list = field(default_factory=list)
    kept: list = field(default_factory=list)
    selection: tuple | None = None


@dataclass
class Refinement:
    """What ``Detector.refine`` made of a predicted pose. ``in_view`` is False when the pose puts the model
    behind the camera or out of the image (nothing can be said about it); ``detection`` is None when too little
    measured depth lies around the predicted pose to refine it, else the refined, verified pose."""

    in_view: bool
    detection: Detection | None = None


# a grid step this many times the finest gets its own keypoints, as the model would alone (the finest grid thinned
# to it would keep one sample in OWN_GRID_RATIO^2 or more on a surface, an arbitrary one, not the voxel's most
# central); a finer step takes the finest keypoints, thinned (most of them)
OWN_GRID_RATIO = 1.5
SURFACE_SAMPLES = 128  # model samples that tell two candidate poses' surfaces apart (_spread_per_model)


def _spread_per_model(indices: list[int], looks, hyps: list[Hypothesis], poses: dict, models: list[PreparedModel],
                      limit: int, *, spots: dict[int, int] | None = None, places: int = 0) -> list[int]:
    """Per model, up to ``limit`` of ``indices`` (into ``hyps``, posed at ``poses[j]``), best-looking first
    (``looks[j].score``, ties by index), none within 10 degrees and a fifth of the diameter of a better-looking
    one. The first ``spots[model index]`` (default: all ``limit``) are taken on distinct spots of the scene:
    each puts the model's surface somewhere else than every better-looking one (a mean closest-point distance
    of a tenth of the diameter or more, ``grouping.common.distinct_surfaces``), so that three copies of an
    object, or a box turned every way on one spot, do not take the whole budget; the rest are the
    best-looking left, alternatives on the same spots (when one instance is wanted, a flange turned by one
    bolt hole is worth refining). Where those cover fewer than ``places`` places (``_places``), the
    best-looking of the others at new places are added, beyond ``limit``: in a scene of many objects, another
    object's surface can look best for a model at every turn (a flat bracket on a box's faces), and its own
    place must still be refined."""
    out = []
    for mi in sorted({hyps[j].model_index for j in indices}):
        js = sorted((j for j in indices if hyps[j].model_index == mi), key=lambda j: (-looks[j].score, j))
        pm = models[mi]
        T = np.array([poses[j] for j in js])
        order = distinct_poses(T, np.arange(len(js)), pm.model.diameter, len(js))
        n_spots = limit if spots is None else min(limit, spots.get(mi, limit))
        step = max(1, -(-len(pm.icp_points) // SURFACE_SAMPLES))
        first = distinct_surfaces(T, order, pm.icp_points[::step], pm.model.diameter, n_spots)
        taken = set(first.tolist())
        rest = [i for i in order if i not in taken][:limit - len(first)]
        chosen = sorted([*taken, *rest])  # positions in js: best-looking first
        if places > 0:
            centres = _centres(T, pm)
            inside = set(chosen)
            chosen += _places(centres, chosen, [i for i in order if i not in inside], 0.5 * pm.model.diameter, places)
        out += [js[i] for i in sorted(chosen)]
    return out


def _places(centres: np.ndarray, chosen: list[int], others: list[int], apart: float, places: int, *,
            beyond: bool = False) -> list[int]:
    """Of ``others`` (indices into ``centres`` (N, 3), m, best first), the first at new places, until ``chosen``
    and they cover ``places`` places (with ``beyond``: until they add ``places`` to those ``chosen`` covers): a
    place is a centre at least ``apart`` (m) from every place's first centre, counted over ``chosen`` in its order
    first."""
    at: list[np.ndarray] = []

    def new(i: int) -> bool:
        return all(np.sum((centres[i] - a) ** 2) >= apart * apart for a in at)

    for i in chosen:
        if new(i):
            at.append(centres[i])
    if beyond:
        places += len(at)
    added = []
    for i in others:
        if len(at) >= places:
            break
        if new(i):
            added.append(i)
            at.append(centres[i])
    return added


def _more_places(indices: list[int], looks, hyps: list[Hypothesis], poses: dict, models: list[PreparedModel], *,
                 refined: list[int], short: set[int], places: int) -> list[int]:
    """For each model index in ``short``, the best-looking of ``indices`` (into ``hyps``, posed at ``poses[j]``;
    ``looks[j].score``) that lie at new places, up to ``places`` of them: a place as in ``_places`` (half the
    model's diameter), new where none of the model's ``refined`` candidates lies."""
    out = []
    done = set(refined)
    for mi in sorted(short):
        ref = [j for j in refined if hyps[j].model_index == mi]
        rest = sorted((j for j in indices if hyps[j].model_index == mi and j not in done),
                      key=lambda j: (-looks[j].score, j))
        if not rest:
            continue
        pm = models[mi]
        cand = ref + rest
        centres = _centres(np.array([poses[j] for j in cand]), pm)
        out += [cand[i] for i in _places(centres, list(range(len(ref))), list(range(len(ref), len(cand))),
                                         0.5 * pm.model.diameter, places, beyond=True)]
    return out


def _centres(T: np.ndarray, pm: PreparedModel) -> np.ndarray:
    """(N, 3) m: the centroid of ``pm``'s ICP samples at each pose of ``T`` (N, 4, 4)."""
    return T[:, :3, :3] @ pm.icp_points.mean(axis=0) + T[:, :3, 3]


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

    def __init__(self, library: ModelLibrary, config: PipelineConfig | None = None, *, workers: int | None = None):
        """``workers``: threads for the per-model and per-hypothesis work (default: the machine's cores). Every
        task is independent and has its own generator, so the output is the same for any number."""
        from ._o3d import o3d  # noqa: F401  every frame needs open3d (normals, ray casting): imported here, its
        # 0.7-0.8 s are not charged to the first frame's preprocessing (0.88 s against 0.09 s on the YCB-V frame)
        self.library = library
        self.config = config or PipelineConfig()
        self.workers = max(1, workers or os.cpu_count() or 1)
        self._pool = ThreadPoolExecutor(self.workers) if self.workers > 1 else None
        self.grouper = make_grouper(self.config.grouping)
        icp_spacing = 2 * self.config.preprocess.voxel
        self.models = [PreparedModel.build(m, i, icp_spacing=icp_spacing) for i, m in enumerate(library)]
        # look-alikes (one shape at several sizes) are grouped once, for their family's representative
        self.families: list[Family] = look_alike_families(
            [pm.model.points for pm in self.models], [pm.reference for pm in self.models],
            [pm.model.diameter for pm in self.models], self.config.grouping.look_alike)
        self._family = {m: f for f in self.families for m in f.members}
        self._indexes: dict[tuple[int, ...], LibraryIndex] = {}

    def __repr__(self) -> str:
        return (f"Detector({len(self.library)} models, grouping={self.config.grouping.method!r}, "
                f"selection={self.config.verify.selection!r}, workers={self.workers})")

    def _map(self, fn, items) -> list:
        """``[fn(x) for x in items]``, on the thread pool when there is one; results keep the input order."""
        items = list(items)
        if self._pool is None or len(items) < 2:
            return [fn(x) for x in items]
        return list(self._pool.map(fn, items))

    def keypoint_spacing(self, models: list[PreparedModel]) -> float:
        """m; scene keypoints are described this far apart: ``keypoints.spacing``, or for large models no denser
        than grouping uses them (the smallest searched diameter / ``grouping.grid_per_diameter``)."""
        return min((self.grid_step(pm) for pm in models), default=self.config.keypoints.spacing)

    def grid_step(self, pm: PreparedModel) -> float:
        """m; the spacing of the scene keypoints ``pm`` groups: its diameter / ``grouping.grid_per_diameter``, no
        finer than ``keypoints.spacing`` (large models need no denser grid)."""
        cfg = self.config
        return max(cfg.keypoints.spacing, pm.model.diameter / cfg.grouping.grid_per_diameter)

    def family_of(self, model_index: int) -> Family:
        """The family of look-alikes the model at ``model_index`` belongs to (itself alone when it has none)."""
        return self._family[model_index]

    def grouped(self, models: list[PreparedModel]) -> list[PreparedModel]:
        """The models whose correspondences are grouped to find ``models``: the representative of each family of
        look-alikes (``look_alikes``) with a member among them, in library order (each model itself when the
        library has no look-alikes)."""
        want = {pm.index for pm in models}
        reps = sorted(f.representative for f in self.families if want.intersection(f.members))
        return [self.models[i] for i in reps]

    def scene(self, frame: Frame, tm: _Timer | None = None, models: list[PreparedModel] | None = None) -> Scene:
        """The frame's ``Scene`` for finding ``models`` (default: all): preprocessed cloud (the support's height
        set by the largest of them), keypoints and their FPFH; with a colour image, the keypoints' chromaticity,
        and when every model has colour, only the keypoints whose colour some model has.

        Voxel keypoints are chosen at the finest model's grid step and, at once, at every grid step
        ``OWN_GRID_RATIO`` times coarser or more (``voxel_keypoint_levels``): a large model beside small ones
        groups the keypoints it groups when searched alone, not one arbitrary sample in several of the finest
        grid; the descriptors are computed once, on the union. Look-alikes take their representative's grid."""
        cfg, tm = self.config, tm or _Timer()
        models = self.models if models is None else models
        grouped = self.grouped(models)
        with tm("preprocess"):
            size = max((pm.model.diameter for pm in models), default=0.3)
            cloud = preprocess(frame, cfg.preprocess, cfg.seed, model_size=size, workers=self.workers)
        with tm("keypoints"):
            levels = None
            if cfg.keypoints.method == "voxel":
                # a step under OWN_GRID_RATIO times the finest takes the finest keypoints, thinned (most of them)
                fine = self.keypoint_spacing(grouped)
                own = [s for s in (self.grid_step(pm) for pm in grouped) if s >= OWN_GRID_RATIO * fine]
                kp, levels = voxel_keypoint_levels(cloud.points, own + [fine])
            else:
                kp = select_keypoints(cloud.points, cfg.keypoints)
            colours = None
            palette = [pm.colours for pm in models if pm.colours is not None]
            if frame.rgb is not None and cfg.matching.colour_gate > 0 and palette:  # colour matters to a model
                colours = chromaticity(image_colours(cloud.points[kp], frame.camera, frame.rgb))
                if len(palette) == len(models):
                    # a keypoint whose colour no model has can match nothing: it is not described at all
                    keep = colour_within(colours, np.concatenate(palette), cfg.matching.colour_gate)
                    kp, colours = kp[keep], colours[keep]
                    if levels is not None:
                        at = np.cumsum(keep) - 1  # new position of each kept keypoint
                        levels = {s: at[i[keep[i]]] for s, i in levels.items()}
        with tm("features"):
            feats = fpfh(cloud.points, cloud.normals, kp, cfg.features, workers=self.workers)
        return Scene(cloud.points, cloud.normals, cloud.labels, cloud.plane, kp, feats,
                     lrf_radius=cfg.features.lrf_support, colours=colours, workers=self.workers, levels=levels)

    def _hypotheses(self, scene: Scene, models: list[PreparedModel], tm: _Timer, trace: Trace | None = None, *,
                    given: bool = False) -> list[Hypothesis]:
        """Match the scene's keypoints against each model (or, with ``matching.library_pool``, against one index
        over all of them) and group the candidates into pose hypotheses, one model per thread, each with its own
        generator (so neither order nor threads change the result). ``given``: the models were named as targets
        (they are in view), so the keypoints each groups are chosen by ``grouping.distinct`` too."""
        cfg = self.config
        seeds = np.random.SeedSequence(cfg.seed).spawn(len(self.library))
        spacing = self.keypoint_spacing(models) if cfg.keypoints.method == "voxel" else cfg.keypoints.spacing
        mc = cfg.matching

        def view_of(pm: PreparedModel) -> SceneKeypoints:
            # large models need no denser grid of scene points than diameter / grid_per_diameter
            return scene.keypoints_at(self.grid_step(pm), min_step=spacing)

        chosen: dict[int, np.ndarray] = {}  # per model: the view's rows it groups, when matching chose them
        gc = cfg.grouping
        with tm("matching"):
            # with targets, keypoints unlike the rest of the scene come first (grouping.distinct), where the bound
            # can bite
            bound = 0 < gc.max_keypoints < len(scene.keypoints)
            spread = scene.spread(gc.distinct, mc.screen_eps) if given and gc.distinct > 0 and bound else None
            if len(models) > 1 and mc.library_pool > 0 and mc.ratio >= 1 and not mc.mutual:
                # one search over the library: a model gets candidates only where the scene resembles it
                found = match_library(scene.descriptors, self._library_index(models), mc, workers=self.workers,
                                      scene_colours=scene.colours)
                cands = {pm.index: c for pm, c in zip(models, found)}
            else:
                cands = {}
                for pm in models:
                    # only the keypoints the model groups are matched (each query is independent); with the
                    # mutual test every keypoint is, since it asks which scene keypoint is nearest
                    rows = np.arange(len(scene.keypoints)) if mc.mutual else view_of(pm).index
                    colours = None if scene.colours is None else scene.colours[rows]
                    kw = dict(model_tree=pm.descriptor_tree, workers=self.workers, scene_colours=colours,
                              model_colours=pm.colours)
                    if mc.mutual:
                        found = match_features(scene.descriptors[rows], pm.model.features, mc, **kw)
                    else:  # the keypoints within grouping.max_keypoints are chosen here (on the view's rows)
                        found, chosen[pm.index] = match_bounded(
                            scene.descriptors[rows], pm.model.features, mc, gc.max_keypoints,
                            spread=None if spread is None else spread[rows], **kw)
                    cands[pm.index] = found.placed(rows, len(scene.keypoints))
        if self.grouper.needs_lrfs:
            with tm("lrf"):  # only keypoints with a candidate take part in grouping
                used = np.zeros(len(scene.keypoints), bool)
                for c in cands.values():
                    used |= (c.model >= 0).any(axis=1)
                scene.lrfs_of(np.flatnonzero(used))
        if trace is not None:
            trace.candidates = cands
            trace.grid = {pm.index: view_of(pm).index for pm in models}
        with tm("grouping"):
            def group(pm: PreparedModel) -> list[Hypothesis]:
                view = view_of(pm)
                rows = cands[pm.index].rows(view.index)
                has = chosen.get(pm.index)
                if has is None:  # mutual or library matching: the bound is applied here, as match_bounded does
                    cap = gc.max_keypoints
                    has = (rows.nearest_rows(cap, None if spread is None else spread[view.index]) if cap
                           else (rows.model >= 0).any(axis=1))
                if not has.all():  # keypoints left without a candidate (by colour) take no part in grouping
                    view, rows = view.subset(has), Candidates(rows.model[has], rows.distance[has])
                if trace is not None:
                    trace.grouped[pm.index] = view.index
                return self.grouper.group(view, pm, rows, np.random.default_rng(seeds[pm.index]),
                                          workers=max(1, self.workers // len(models)))

            return [h for hs in self._map(group, models) for h in hs]

    def _look_alike_hypotheses(self, raw: list[Hypothesis], searched: set[int]) -> tuple[list[Hypothesis], list[int]]:
        """The raw hypotheses of the grouped models as hypotheses of each searched member of their family (a
        look-alike's pose moved by ``look_alikes.transfer``; its correspondences are the representative's), in
        model order and then in the order found; and for each, the index into ``raw`` it came from. Without
        look-alikes this is ``raw`` itself."""
        by_model: dict[int, list[int]] = {}
        for i, h in enumerate(raw):
            for m in self._family[h.model_index].members:
                if m in searched:
                    by_model.setdefault(m, []).append(i)
        hyps, source = [], []
        for m in sorted(by_model):
            for i in by_model[m]:
                h = raw[i]
                if m != h.model_index:
                    h = Hypothesis(m, self._as_member(h.T_scene_model, h.model_index, m), h.inliers, h.group)
                hyps.append(h)
                source.append(i)
        return hyps, source

    def _as_member(self, T_scene_model: np.ndarray, model_index: int, member: int) -> np.ndarray:
        """(4, 4) pose of the look-alike ``member`` where the model at ``model_index`` is posed at ``T_scene_model``
        (``look_alikes.transfer``; the pose itself when ``member`` is that model)."""
        if member == model_index:
            return T_scene_model
        return transfer(T_scene_model, self.models[model_index].reference, self.models[member].reference)

    def _library_index(self, models: list[PreparedModel]) -> LibraryIndex:
        """The descriptor index over ``models``, built on first use for each set of models searched."""
        key = tuple(pm.index for pm in models)
        if key not in self._indexes:
            self._indexes[key] = LibraryIndex.build([pm.model.features for pm in models],
                                                    [pm.colours for pm in models])
        return self._indexes[key]

    def _select_global(self, scene: Scene, order, hyps, regs, vers, trace: Trace | None = None, *,
                       targets: dict[int, int] | None = None) -> list[int]:
        """The subset of ``order`` (indices of accepted hypotheses) that best explains the scene
        (``global_verify``), with at most ``targets[obj_id]`` poses of each object where given, best verification
        score first; its inputs go to ``trace.selection``."""
        v = self.config.verify
        pts = [transform(regs[j].T_target_source, self.library[hyps[j].model_index].points) for j in order]
        ratio = np.array([vers[j].n_violations / max(vers[j].n_supported, 1) for j in order])
        terms = candidate_terms(scene.points, pts, ratio, v.explain_radius, v.clutter_radius,
                                plane=scene.plane, scene_normals=scene.normals)
        # two sizes of one shape on one spot are one object, as two poses of one model are
        family = [self._family[hyps[j].model_index].representative for j in order]
        conflicts = same_object_conflicts(terms, family, v.conflict_overlap)
        if trace is not None:
            trace.selection = (terms, conflicts)
        groups = None if targets is None else [self.library[hyps[j].model_index].obj_id for j in order]
        chosen, _ = select(terms, v.duplicate_weight, v.clutter_weight, v.violation_weight, conflicts=conflicts,
                           groups=groups, caps=targets)
        return [order[i] for i in sorted(chosen)]

    def _select_targets(self, frame: Frame, scene: Scene, order: list[int], hyps: list[Hypothesis],
                        regs: list[RegistrationResult], vers: list[Verification], *, targets: dict[int, int],
                        trace: Trace | None = None) -> list[int]:
        """With targets: walking ``order`` (verified candidates, best score first), each candidate is kept unless
        a kept one claims more than ``verify.conflict_overlap`` of its pixels (``resolve_conflicts``), and each
        object keeps its first ``targets[obj_id]``. When that leaves an object short of the instances it has
        candidates for (a better-scoring pose of another object took their pixels: a bracket laid onto a step
        block, scoring above the step block's true pose), or keeps a pose of an object that scores below one of
        its poses that lost its pixels so (the step block kept elsewhere at 0.75 where its true pose scored 0.88),
        and selection is global, the walk is redone with the set that best explains the scene
        (``_select_global``) first, so that the object explaining the spot keeps it and the other takes its next
        pose elsewhere, if any. That set holds no more poses of an object than its count (``global_verify.select``'s
        caps): beyond it, a pose (a second step block where the bracket stands, scoring 0.41) would be dropped by
        the count after taking the pixels of the pose that explains its spot (the bracket's, 0.71). Returns the
        kept candidates, best score first."""
        v = self.config.verify
        supports = [x.support for x in vers]
        obj = [self.library[h.model_index].obj_id for h in hyps]

        def take(walk: list[int]) -> list[int]:
            left, chosen = dict(targets), []
            for j in resolve_conflicts(walk, supports, v.conflict_overlap, frame.depth.size):
                if left.get(obj[j], 0) > 0:
                    chosen.append(j)
                    left[obj[j]] -= 1
            return chosen

        chosen = take(order)
        has = {o: sum(obj[j] == o for j in order) for o in targets}
        got = {o: sum(obj[j] == o for j in chosen) for o in targets}
        rank = {j: n for n, j in enumerate(order)}
        last = {}  # per object, the rank of its last kept candidate
        for k in chosen:
            last[obj[k]] = max(last.get(obj[k], -1), rank[k])
        kept = set(chosen)
        # a candidate walked before one kept of its object was not left out by the count: it lost its pixels
        passed_over = any(j not in kept and rank[j] < last.get(obj[j], -1) for j in order)
        if v.selection != "global" or (all(got[o] >= min(n, has[o]) for o, n in targets.items())
                                       and not passed_over):
            return chosen
        first = self._select_global(scene, order, hyps, regs, vers, trace, targets=targets)
        taken = set(first)
        return sorted(take(first + [j for j in order if j not in taken]), key=rank.get)  # best score first

    def _one_size_per_spot(self, frame: Frame, scene: Scene, order: list[int], hyps: list[Hypothesis],
                           regs: list[RegistrationResult], vers: list[Verification]) -> list[int]:
        """``order`` (indices of verified candidates) without the look-alikes beaten on their spot, where two sizes
        of one shape (members of one family) claim the same pixels (more than ``verify.conflict_overlap`` of the
        smaller support). First the fitted scale (``refine.scale_fit``, the size ICP would give the model if it
        could scale it): a size whose scale is further from 1 than another's by more than ``verify.size_margin``
        (in log scale) loses to it, where the view fixes both. Of those left, only the size whose outline fits
        best stays (``verify.size_fit``, ties by index). The verification score alone prefers a model slightly
        too small: all of it lies on the object."""
        v = self.config.verify
        multi = [j for j in order if len(self._family[hyps[j].model_index].members) > 1]
        if len(multi) < 2:
            return order

        def rivals(j: int, k: int) -> bool:
            mj, mk = hyps[j].model_index, hyps[k].model_index
            sj, sk = vers[j].support, vers[k].support
            return (mj != mk and self._family[mj] is self._family[mk]
                    and len(np.intersect1d(sj, sk, assume_unique=True)) > v.conflict_overlap * min(len(sj), len(sk)))

        pairs = [(j, k) for n, j in enumerate(multi) for k in multi[n + 1:] if rivals(j, k)]
        if not pairs:
            return order
        rival = {frozenset(p) for p in pairs}
        beaten: set[int] = set()
        if v.size_margin > 0:
            misfit = {j: self._scale_misfit(scene, hyps[j].model_index, regs[j].T_target_source)
                      for j in sorted({j for p in pairs for j in p})}  # one after the other, as verification
            for j, k in pairs:
                (mj, sdj), (mk, sdk) = misfit[j], misfit[k]
                if max(sdj, sdk) <= v.size_margin / 4 and abs(mj - mk) > v.size_margin:
                    beaten.add(j if mj > mk else k)
        multi = [j for j in multi if j not in beaten]

        def fit(j: int) -> float:
            mi = hyps[j].model_index
            cont = continuing_surface(self.library[mi], regs[j].T_target_source, frame.depth, frame.camera,
                                      tolerance=v.depth_tolerance, ring=v.size_ring,
                                      spacing=self.config.preprocess.voxel, caster=self.models[mi].caster)
            return size_fit(vers[j], cont)

        fits = {j: fit(j) for j in multi}  # one after the other, as verification (``_verify``)
        kept: list[int] = []
        for j in sorted(multi, key=lambda j: (-fits[j], j)):
            if not any(frozenset((j, k)) in rival for k in kept):
                kept.append(j)
        beaten |= set(multi) - set(kept)
        return [j for j in order if j not in beaten]

    def _scale_misfit(self, scene: Scene, model_index: int, T_cam_model: np.ndarray) -> tuple[float, float]:
        """(|log s|, sd of s) of the scale ``refine.scale_fit`` gives the model at ``T_cam_model`` on the scene."""
        pm = self.models[model_index]
        s, sd = scale_fit(pm.icp_points, scene.points, scene.normals, T_cam_model, self.config.refine,
                          source_normals=pm.icp_normals, target_tree=scene.tree, viewpoint=np.zeros(3))
        return abs(float(np.log(s))) if s > 0 else float("inf"), sd

    def _verify(self, frame: Frame, scene: Scene | None, model_index: int, T_cam_model: np.ndarray,
                stride: int = 1) -> Verification:
        """``verify`` of one pose (``_verify_poses`` of one)."""
        return self._verify_poses(frame, scene, [(model_index, T_cam_model)], stride)[0]

    def _verify_poses(self, frame: Frame, scene: Scene | None, poses: list[tuple[int, np.ndarray]],
                      stride: int = 1) -> list[Verification]:
        """``verify`` of each ``(model index, T_cam_model)`` in ``poses``, in order; each model's poses are cast
        at once (``verify.verify_poses``). Not on the thread pool: open3d's ray casting already uses every core,
        and on two cores two verifications at once took longer than one after the other (8-object real frames
        0.93-0.98 of the time a frame; one-model frames the same)."""
        cfg = self.config
        by_model: dict[int, list[int]] = {}
        for n, (mi, _) in enumerate(poses):
            by_model.setdefault(mi, []).append(n)
        out: list[Verification | None] = [None] * len(poses)
        for mi, ns in by_model.items():
            pm = self.models[mi]
            found = verify_poses(pm.model, [poses[n][1] for n in ns], frame.depth, frame.camera, cfg.verify,
                                 spacing=cfg.preprocess.voxel, plane=None if scene is None else scene.plane,
                                 stride=stride, caster=pm.caster, hull=pm.hull)
            for n, v in zip(ns, found):
                out[n] = v
        return out

    def _coarse_icp(self, scene: Scene, poses: list[tuple[int, np.ndarray]]) -> list[np.ndarray]:
        """Raw poses ``(model index, T_scene_model)`` each moved by two short rounds of ICP on a sparse sample of
        its model, with wide correspondence distances (``refine.coarse_distance``, then two thirds of it); all of
        them at once (``refine.icp_many``)."""
        rc = self.config.refine
        src, nrm = [], []
        for mi, _ in poses:
            pm = self.models[mi]
            step = max(1, -(-len(pm.icp_points) // rc.coarse_points))
            src.append(pm.icp_points[::step])
            nrm.append(pm.icp_normals[::step])
        T = [T0 for _, T0 in poses]
        for d in (rc.coarse_distance, rc.coarse_distance * 2 / 3):
            T = [r.T_target_source for r in icp_many(
                src, scene.points, scene.normals, T, RefineConfig(iterations=8, max_distance=d, kernel=d / 2),
                source_normals=nrm, target_tree=scene.tree, viewpoint=np.zeros(3), workers=self.workers)]
        return T

    def _icp(self, pm: PreparedModel, points, normals, T_init, tree=None) -> RegistrationResult:
        return icp(pm.icp_points, points, normals, T_init, self.config.refine, source_normals=pm.icp_normals,
                   target_tree=tree, viewpoint=np.zeros(3))

    @on_one_blas_thread
    def detect(self, frame: Frame, targets: dict[int, int] | None = None, *, trace: Trace | None = None
               ) -> DetectionResult:
        """Detect objects in ``frame``.

        targets : optional ``{obj_id: count}`` (BOP localisation): only those objects are searched and the
            ``count`` best-scoring verified instances of each are kept, without the score threshold.
        trace : a ``Trace`` to fill with the intermediate results (``pcdet.diagnose`` reads it).

        BLAS runs on one thread meanwhile (``pcdet.blas``): the work is spread over the detector's own threads.
        """
        return self._detect(frame, targets, trace)

    def _detect(self, frame: Frame, targets: dict[int, int] | None, trace: Trace | None) -> DetectionResult:
        cfg = self.config
        tm = _Timer()
        models = [pm for pm in self.models if targets is None or pm.model.obj_id in targets]
        # distinct spots of the scene each model's budget covers first: the instances wanted (all, without targets)
        spots = None if targets is None else {pm.index: targets[pm.model.obj_id] for pm in models}
        scene = self.scene(frame, tm, models)
        stats = {"scene_points": len(scene.points), "scene_keypoints": len(scene.keypoints)}
        raw = self._hypotheses(scene, self.grouped(models), tm, trace, given=targets is not None)
        # a look-alike takes its representative's raw poses
        hyps, source = self._look_alike_hypotheses(raw, {pm.index for pm in models})
        stats["hypotheses"] = len(hyps)
        if trace is not None:
            trace.scene, trace.hypotheses = scene, list(hyps)
        if len(hyps) == 0 or len(scene.points) == 0:
            stats["refined"] = stats["detections"] = 0
            return DetectionResult([], tm.t, stats)
        with tm("verify"):
            # cheap first look at the raw poses (a look-alike's is its representative's): only plausible ones are
            # worth an ICP
            used = sorted(set(source))
            looks = dict(zip(used, self._verify_poses(frame, scene, [(raw[i].model_index, raw[i].T_scene_model)
                                                                    for i in used], stride=2)))
        first_looks = looks  # the coarse stage below rebinds ``looks``
        # a short coarse ICP for the best raw hypotheses of each grouped model (a family of look-alikes: of its
        # representative, whose coarse pose and look every member then takes), then the full ICP for the best few
        # of each model
        rc = cfg.refine
        plausible = [i for i in used if looks[i].score >= cfg.verify.prefilter and looks[i].n_supported > 0]
        start = {i: raw[i].T_scene_model for i in plausible}
        if rc.candidates > 0:
            # raw poses on distinct spots first: near-copies of one pose would all slide to the same place,
            # and the budget would go to one instance of a crowded scene (or to one box turned every way); with
            # targets, at ``places`` places at least, as the full ICPs below: a place that no coarse ICP reaches
            # cannot be refined fully there either
            raw_spots = None
            if spots is not None:
                raw_spots = {}
                for mi, n in spots.items():
                    rep = self._family[mi].representative
                    raw_spots[rep] = max(n, raw_spots.get(rep, 0))
            coarse = _spread_per_model(plausible, looks, raw, start, self.models, rc.candidates, spots=raw_spots,
                                       places=0 if spots is None else rc.places)
            with tm("refine"):
                moved = self._coarse_icp(scene, [(raw[i].model_index, raw[i].T_scene_model) for i in coarse])
            with tm("verify"):
                second = self._verify_poses(frame, scene, [(raw[i].model_index, T) for i, T in zip(coarse, moved)],
                                            stride=2)
            # the coarse ICP can also slide a good raw pose onto a neighbour: keep whichever looks better
            better = [v.score >= looks[i].score for i, v in zip(coarse, second)]
            looks = {i: (v if b else looks[i]) for i, v, b in zip(coarse, second, better)}
            start = {i: (T if b else raw[i].T_scene_model) for i, T, b in zip(coarse, moved, better)}
            plausible = [i for i in coarse if looks[i].n_supported > 0]
            if trace is not None:
                given = set(coarse)
                trace.coarse = [j for j in range(len(hyps)) if source[j] in given]
        # each searched model takes the coarse poses of the raw hypotheses it came from
        reached = set(plausible)
        plausible = [j for j in range(len(hyps)) if source[j] in reached]
        look = {j: looks[source[j]] for j in plausible}
        start = {j: self._as_member(start[source[j]], raw[source[j]].model_index, hyps[j].model_index)
                 for j in plausible}
        # the full ICP for the best few per model, on distinct spots first; candidates that converged onto the
        # same pose are one (the best-looking of them)
        keep = sorted(_spread_per_model(plausible, look, hyps, start, self.models, rc.max_per_model, spots=spots,
                                        places=0 if spots is None else rc.places))
        hyps_all, hyps = hyps, [hyps[j] for j in keep]
        regs, vers = self._refine_and_verify(frame, scene, [(h.model_index, start[j]) for h, j in zip(hyps, keep)], tm)
        with tm("verify"):
            order, kept = self._select(frame, scene, hyps, regs, vers, targets=targets, trace=trace)
        if targets is not None and rc.retry_places > 0:
            # an object given but left short: its own place may be among the coarse candidates never fully refined
            got = Counter(self.library[hyps[j].model_index].obj_id for j in kept)
            short = {o for o, n in targets.items() if got[o] < n}
            more = _more_places(plausible, look, hyps_all, start, self.models, refined=keep,
                                short={pm.index for pm in models if pm.model.obj_id in short}, places=rc.retry_places)
            if more:
                more_regs, more_vers = self._refine_and_verify(
                    frame, scene, [(hyps_all[j].model_index, start[j]) for j in more], tm)
                keep, hyps = keep + more, hyps + [hyps_all[j] for j in more]
                regs, vers = regs + more_regs, vers + more_vers
                with tm("verify"):
                    order, kept = self._select(frame, scene, hyps, regs, vers, targets=targets, trace=trace)
        stats["refined"] = len(hyps)
        if trace is not None:
            trace.first_look, trace.refined = [first_looks[i] for i in source], keep
            trace.registrations, trace.verifications, trace.accepted, trace.kept = regs, vers, order, kept
        dets = [self._detection(frame, hyps[j].model_index, regs[j], vers[j], hyps[j].n_inliers, hyps[j].group)
                for j in kept]
        stats["detections"] = len(dets)
        return DetectionResult(dets, tm.t, stats)

    def _refine_and_verify(self, frame: Frame, scene: Scene, poses: list[tuple[int, np.ndarray]], tm: _Timer
                           ) -> tuple[list[RegistrationResult], list[Verification]]:
        """The full ICP of each ``(model index, T_scene_model)`` of ``poses`` (all at once, ``refine.icp_many``),
        and the verification of its result."""
        pms = [self.models[mi] for mi, _ in poses]
        with tm("refine"):
            regs = icp_many([pm.icp_points for pm in pms], scene.points, scene.normals, [T for _, T in poses],
                            self.config.refine, source_normals=[pm.icp_normals for pm in pms],
                            target_tree=scene.tree, viewpoint=np.zeros(3), workers=self.workers)
        with tm("verify"):
            vers = self._verify_poses(frame, scene, [(mi, r.T_target_source) for (mi, _), r in zip(poses, regs)])
        return list(regs), vers

    def _select(self, frame: Frame, scene: Scene, hyps: list[Hypothesis], regs: list[RegistrationResult],
                vers: list[Verification], *, targets: dict[int, int] | None, trace: Trace | None
                ) -> tuple[list[int], list[int]]:
        """(order, kept): the refined candidates in play, best score first (without targets, those accepted), and
        those selection keeps (``_select_targets``, ``_select_global`` or greedy on claimed pixels)."""
        v = self.config.verify
        order = sorted(range(len(hyps)), key=lambda j: (-vers[j].score, j))
        if targets is None:
            order = [j for j in order if vers[j].accepted(v)]
        else:
            order = [j for j in order if vers[j].n_supported > 0]
        order = self._one_size_per_spot(frame, scene, order, hyps, regs, vers)
        if targets is not None:
            kept = self._select_targets(frame, scene, order, hyps, regs, vers, targets=targets, trace=trace)
        elif v.selection == "global":
            kept = self._select_global(scene, order, hyps, regs, vers, trace)
        else:
            kept = resolve_conflicts(order, [x.support for x in vers], v.conflict_overlap, frame.depth.size)
        return order, kept

    def _detection(self, frame: Frame, model_index: int, reg: RegistrationResult, ver: Verification,
                   n_inliers: int, group: int) -> Detection:
        m = self.library[model_index]
        return Detection(m.name, m.obj_id, ver.score, frame.T_input_cam @ reg.T_target_source, n_inliers,
                         reg.fitness, reg.rmse_m, ver.visible_fraction, group)

    @on_one_blas_thread
    def refine(self, frame: Frame, model_index: int, T_cam_model: np.ndarray, *, depth_margin: float = 0.03,
               pixel_margin: int = 8, min_points: int = 50) -> Refinement:
        """Refine a predicted pose of one model in ``frame`` and verify it (tracking between full detections).

        Only the measured depth around the prediction takes part: pixels in the model's projected box (grown
        by ``pixel_margin``) whose depth lies within ``depth_margin`` m of the model's depth range. They are
        gridded and given normals as a scene is, ICP moves the model's samples from ``T_cam_model`` (camera
        frame, 4 x 4), and the result is checked against the depth (every second row and column).
        ``min_points``: fewer such pixels and there is nothing to refine on. BLAS runs on one thread meanwhile.
        """
        cfg, cam, depth = self.config, frame.camera, frame.depth
        P = transform(T_cam_model, self.library[model_index].points)
        if np.any(P[:, 2] <= 0.05):
            return Refinement(False)
        pix = bbox_pixels(cam, P, margin=pixel_margin)
        if pix is None or len(pix) < 25:
            return Refinement(False)
        z = depth.reshape(-1)[pix]
        keep = (z > P[:, 2].min() - depth_margin) & (z < P[:, 2].max() + depth_margin)
        if keep.sum() < min_points:
            return Refinement(True)
        S, _, _ = voxel_downsample(cam.backproject_pixels(pix[keep], z[keep]), cfg.preprocess.voxel,
                                   representatives=False)
        N = estimate_normals(S, cfg.preprocess.normal_radius, cfg.preprocess.normal_max_nn, workers=self.workers)
        reg = self._icp(self.models[model_index], S, N, T_cam_model)
        ver = self._verify(frame, None, model_index, reg.T_target_source, stride=2)
        return Refinement(True, self._detection(frame, model_index, reg, ver, reg.n_inliers, 0))
