"""The whole pipeline on real data with ground truth, and its determinism."""
import json

import numpy as np
import pytest

from pcdet.config import PipelineConfig, load_pipeline
from pcdet.datasets.bop import BopDataset
from pcdet.detector import Detector
from pcdet.frame import Frame
from pcdet.library import ModelLibrary
from pcdet.metrics import adds, rotation_error_deg

from .conftest import shared


@pytest.mark.real
@pytest.mark.parametrize("model_file", ["model_milk.pcd", "model_milk_crop.pcd"])
def test_pcl_milk_found_once_within_5mm_2deg(model_file):
    d = shared("pcl_milk")
    T_gt = np.array(json.loads((d / "gt.json").read_text())["poses"][model_file])
    lib = ModelLibrary.from_files([d / model_file])
    res = Detector(lib).detect(Frame.from_cloud(d / "scene.pcd"))
    assert len(res.detections) == 1
    T = res.detections[0].T_cam_model  # in the scene file's own frame
    assert np.linalg.norm(T[:3, 3] - T_gt[:3, 3]) < 0.005
    assert rotation_error_deg(T[:3, :3], T_gt[:3, :3]) < 2.0


@pytest.mark.real
def test_ycbv_frame_all_three_by_adds():
    """The real YCB-Video frame with its three objects given: the default pipeline puts a detection of each
    within ADD-S 0.1 d of the truth (the mug, obj 14, is the hardest: `pcdet diagnose ../shared/data/ycbv_frame
    --metric adds` shows its table)."""
    ds = BopDataset(shared("ycbv_frame"))
    lib = ModelLibrary.from_folder(ds.models_dir)
    img = ds.images[0]
    res = Detector(lib).detect(ds.frame(img), ds.targets(img))
    good = 0
    for g in ds.gt(img):
        m = lib.by_id(g["obj_id"])
        errs = [adds(d.T_cam_model, g["T_cam_model"], m.points) for d in res.detections if d.obj_id == m.obj_id]
        good += bool(errs) and min(errs) < 0.1 * m.diameter
    assert good == 3, f"{good} of 3 objects within ADD-S 0.1 d"


@pytest.mark.real
def test_linemod_cat_real_frames_default_hough_and_depth_only():
    """Every 4th of the 40 real LINEMOD cat frames (Kinect, heavy clutter, the cat given), its textured scanned
    mesh as the model: the default pipeline finds the cat within ADD 0.1 d in at least 9 of 10, the Hough preset
    in at least 8, and the default on the depth images alone (no colour, as in LM-O) in at least 7 (they find 10,
    9 and 8 today; `pcdet diagnose ../shared/data/linemod_cat` runs all 40)."""
    import dataclasses

    from pcdet.datasets import open_recording
    from pcdet.metrics import add

    rec = open_recording(shared("linemod_cat"))
    frames = list(rec)[::4]
    found = {}
    for preset, colour in (("default", True), ("hough", True), ("default", False)):
        cfg = load_pipeline(preset)
        det = Detector(ModelLibrary.from_folder(shared("linemod_cat") / "models", cfg), cfg)
        m = det.models[0].model
        name = preset if colour else "depth only"
        found[name] = 0
        for r in frames:
            T = next(g["T_cam_model"] for g in rec.gt(r) if g["obj_id"] == m.obj_id)
            frame = rec.frame(r) if colour else dataclasses.replace(rec.frame(r), rgb=None)
            res = det.detect(frame, {m.obj_id: 1})
            found[name] += any(add(d.T_cam_model, T, m.points) < 0.1 * m.diameter for d in res.detections)
    assert found["default"] >= 9 and found["hough"] >= 8 and found["depth only"] >= 7, \
        f"of {len(frames)} frames: {found}"


def test_grouping_sees_at_most_max_keypoints_per_model(synth_small, library):
    """``grouping.max_keypoints`` bounds the scene keypoints each model's grouper works on (the cost of a large
    or depth-only scene); 0 leaves them all."""
    ds = BopDataset(synth_small)
    f = ds.frame(ds.images[0])
    seen = {}
    for cap in (0, 40):
        det = Detector(library, PipelineConfig(seed=4).replace(grouping={"max_keypoints": cap}), workers=1)
        group = det.grouper.group
        sizes = []
        det.grouper.group = lambda view, *a, **kw: sizes.append(len(view.points)) or group(view, *a, **kw)
        det.detect(f, ds.targets(ds.images[0]))
        seen[cap] = sizes
    assert max(seen[0]) > 40 and max(seen[40]) == 40, seen


def test_distinct_keypoints_are_preferred_with_targets_only(synth_small, library):
    """``grouping.distinct`` ranks the keypoints a model groups by candidate distance over their spread in the
    scene (``Scene.spread``), with targets only: there the grouped keypoints differ from the plain ranking's;
    without targets the detector groups the same keypoints and gives the same detections with it as without."""
    from pcdet.detector import Trace

    ds = BopDataset(synth_small)
    img = ds.images[0]
    f = ds.frame(img)
    grouped, found = {}, {}
    for distinct in (0, 32):
        det = Detector(library, PipelineConfig(seed=4).replace(grouping={"max_keypoints": 40, "distinct": distinct}),
                       workers=1)
        for targets in (ds.targets(img), None):
            tr = Trace()
            res = det.detect(f, targets, trace=tr)
            grouped[distinct, targets is None] = {m: v.tolist() for m, v in tr.grouped.items()}
            found[distinct, targets is None] = [(d.obj_id, d.T_cam_model.tolist()) for d in res.detections]
    assert grouped[0, False] != grouped[32, False]
    assert grouped[0, True] == grouped[32, True] and found[0, True] == found[32, True]


def test_same_result_twice(synth_small, library):
    ds = BopDataset(synth_small)
    f = ds.frame(ds.images[0])
    det = Detector(library, PipelineConfig(seed=4))
    a, b = det.detect(f), det.detect(f)
    assert len(a.detections) == len(b.detections) > 0
    for x, y in zip(a.detections, b.detections):
        np.testing.assert_array_equal(x.T_cam_model, y.T_cam_model)
        assert x.score == y.score


def test_trace_keeps_the_inputs_of_global_selection(synth_small, library):
    """``Trace.selection`` holds what global selection chose from: ``select`` on it with the pipeline's weights
    gives the poses kept (as indices into ``accepted``), so weights can be screened without detecting again
    (scripts/selection_weights.py); with threshold selection it stays empty."""
    from pcdet.detector import Trace
    from pcdet.global_verify import select

    ds = BopDataset(synth_small)
    f = ds.frame(ds.images[0])
    cfg = PipelineConfig(seed=4)
    tr = Trace()
    res = Detector(library, cfg).detect(f, trace=tr)
    terms, conflicts = tr.selection
    assert len(terms.explained) == len(tr.accepted) == conflicts.shape[0] > len(res.detections) > 0
    v = cfg.verify
    chosen, _ = select(terms, v.duplicate_weight, v.clutter_weight, v.violation_weight, conflicts=conflicts)
    assert sorted(tr.accepted[i] for i in chosen) == sorted(tr.kept)
    tr = Trace()
    Detector(library, cfg.replace(verify={"selection": "threshold"})).detect(f, trace=tr)
    assert tr.selection is None and len(tr.kept) > 0


def test_empty_scene_gives_no_detection(library):
    from pcdet.synth import KINECT

    depth = np.full((KINECT.height, KINECT.width), 0.9, np.float32)  # a bare wall
    res = Detector(library).detect(Frame(depth, KINECT))
    assert res.detections == []


@pytest.mark.slow
@pytest.mark.parametrize("targets", [None, {1: 1}])
def test_a_frame_of_pure_depth_noise_gives_no_detection(library, targets):
    """Depth drawn uniformly from 1.0-1.3 m in every pixel (no surface, as a sensor facing glare or fog might
    give): grouping finds no raw pose to refine, and the frame gives no detection (before, ICP of an empty batch
    of poses raised an IndexError)."""
    from pcdet.synth import KINECT

    rng = np.random.default_rng(0)
    depth = (1.0 + 0.3 * rng.random((KINECT.height, KINECT.width))).astype(np.float32)
    assert Detector(library).detect(Frame(depth, KINECT), targets).detections == []


def test_same_result_on_one_or_two_threads(synth_small, library):
    ds = BopDataset(synth_small)
    f = ds.frame(ds.images[1])
    a = Detector(library, workers=1).detect(f)
    b = Detector(library, workers=2).detect(f)
    assert [d.to_dict() for d in a.detections] == [d.to_dict() for d in b.detections]
    assert len(a.detections) > 0


@pytest.mark.real
@pytest.mark.parametrize("preset", ["pcl_tutorial", "hough"])
def test_pcl_milk_with_hough_grouping(preset):
    """Issue 3's PCL tutorial case: Hough grouping, at the tutorial's parameters (pipelines/pcl_tutorial.toml)
    and at pcdet's Hough preset, finds the tutorial's milk model once, within 5 mm / 2 deg, from a vote group of
    at least the tutorial's cg_thresh (5) correspondences. Measured: groups 39 (tutorial) and 985 (Hough
    preset), 1.26 mm and 0.10 deg for both."""
    d = shared("pcl_milk")
    T_gt = np.array(json.loads((d / "gt.json").read_text())["poses"]["model_milk.pcd"])
    cfg = load_pipeline(preset)
    res = Detector(ModelLibrary.from_files([d / "model_milk.pcd"], cfg), cfg).detect(Frame.from_cloud(d / "scene.pcd"))
    assert len(res.detections) == 1
    assert res.detections[0].group_size >= 5
    T = res.detections[0].T_cam_model
    assert np.linalg.norm(T[:3, 3] - T_gt[:3, 3]) < 0.005
    assert rotation_error_deg(T[:3, :3], T_gt[:3, :3]) < 2.0


def test_refinement_budget_covers_distinct_spots_first():
    """The ICP budget of one model (``_spread_per_model``): five candidate poses of a 10 cm cube, the three
    best-looking on one spot (the cube turned by its symmetries: the same surface), the other two on spots
    10 and 20 cm away. Without targets (any number of instances) the three slots go to the three spots; with
    one instance wanted, to the best spot's alternatives first, in look order, as before spots were counted."""
    from types import SimpleNamespace

    import trimesh
    from scipy.spatial.transform import Rotation

    from pcdet.detector import _spread_per_model

    cube = trimesh.creation.box((0.1, 0.1, 0.1))
    pts = trimesh.sample.sample_surface(cube, 300, seed=1)[0]
    model = SimpleNamespace(model=SimpleNamespace(diameter=float(np.sqrt(3) * 0.1)), icp_points=pts)
    poses, looks = {}, {}
    for j, (rv, x, score) in enumerate([([0, 0, 0], 0.0, 0.99), ([np.pi / 2, 0, 0], 0.0, 0.98),
                                        ([0, np.pi / 2, 0], 0.0, 0.97), ([0, 0, 0], 0.1, 0.90),
                                        ([0, 0, 0], 0.2, 0.80)]):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(rv).as_matrix()
        T[:3, 3] = [x, 0, 0.8]
        poses[j], looks[j] = T, SimpleNamespace(score=score)
    hyps = [SimpleNamespace(model_index=0)] * 5
    idx = list(range(5))
    assert _spread_per_model(idx, looks, hyps, poses, [model], 3) == [0, 3, 4]
    assert _spread_per_model(idx, looks, hyps, poses, [model], 3, spots={0: 1}) == [0, 1, 2]
    assert _spread_per_model(idx, looks, hyps, poses, [model], 3, spots={0: 2}) == [0, 1, 3]


def test_a_large_model_groups_the_same_keypoints_alone_or_beside_smaller_ones(synth_small, library):
    """Scene keypoints are chosen at the finest grid step and at each step 1.5 times coarser or more
    (``OWN_GRID_RATIO``): a large crate (grid 21 mm) beside the shipped parts (grids of 8-10 mm) groups exactly
    the keypoints, and descriptors, it groups when searched alone, not the 8 mm grid thinned; the parts, all
    under 1.5 times the finest, group the same keypoints as without the crate."""
    import dataclasses

    import trimesh

    from pcdet.detector import OWN_GRID_RATIO
    from pcdet.model import build_model

    crate = build_model(trimesh.creation.box((0.2, 0.12, 0.08)), PipelineConfig(), obj_id=99, name="crate")
    ds = BopDataset(synth_small)
    f = dataclasses.replace(ds.frame(ds.images[0]), rgb=None)
    det = Detector(ModelLibrary(list(library) + [crate]), workers=1)
    big, parts = det.models[-1], det.models[:-1]
    fine = det.keypoint_spacing(parts)
    assert det.grid_step(big) > 2 * fine and max(det.grid_step(pm) for pm in parts) < OWN_GRID_RATIO * fine
    alone, beside, without = (det.scene(f, models=m) for m in ([big], det.models, parts))
    assert set(beside.levels) == {fine, det.grid_step(big)}
    step = det.grid_step(big)
    a, b = alone.keypoints_at(step, min_step=step), beside.keypoints_at(step, min_step=fine)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(alone.descriptors[a.index], beside.descriptors[b.index])
    for pm in parts:
        s = det.grid_step(pm)
        x, y = without.keypoints_at(s, min_step=fine), beside.keypoints_at(s, min_step=fine)
        np.testing.assert_array_equal(x.points, y.points)
        np.testing.assert_array_equal(without.descriptors[x.index], beside.descriptors[y.index])


def _found_with_targets(ds, library, cfg, depth_only: bool = False) -> list[int]:
    """Per image of ``ds``, with its objects given: the ground-truth instances a detector of ``cfg`` finds within
    ADD-S 0.1 d (``depth_only``: without the colour images, as LM-O is evaluated)."""
    import dataclasses

    det, found = Detector(library, cfg), []
    for img in ds:
        frame = ds.frame(img)
        dets = det.detect(dataclasses.replace(frame, rgb=None) if depth_only else frame, ds.targets(img)).detections
        n = 0
        for g in ds.gt(img):
            m = library.by_id(g["obj_id"])
            n += any(d.obj_id == g["obj_id"] and adds(d.T_cam_model, g["T_cam_model"], m.points) < 0.1 * m.diameter
                     for d in dets)
        found.append(n)
    return found


@pytest.mark.slow
def test_with_targets_global_selection_keeps_objects_that_a_walk_by_score_loses(tmp_path, library):
    """8 scenes of 4 parts (synth's default scenes, seed 2026), objects given. Global selection (the default) keeps
    the set of candidates that best explains the depth, where the walk by score alone (``selection =
    "threshold"``) lets a better-scoring pose of another object take an object's pixels (as in scenes 3 and 5,
    where a bracket laid onto the step block scores above the step block's true pose). Global selection finds at
    least 2 instances more over the 8 scenes (32 of 32 against 29 measured) and at least 0.9 of them."""
    from pcdet.synth import SynthConfig, synthesize

    ds = BopDataset(synthesize(library, tmp_path / "suite", SynthConfig(scenes=8, objects=4, seed=2026)))
    total = sum(len(ds.gt(img)) for img in ds)
    best = sum(_found_with_targets(ds, library, PipelineConfig()))
    walk = sum(_found_with_targets(ds, library, PipelineConfig().replace(verify={"selection": "threshold"})))
    assert best >= walk + 2 and best >= 0.9 * total, (best, walk, total)


def test_places_adds_the_best_candidates_at_new_places_until_enough_are_covered():
    """``_places``: the chosen candidates' places count first (two at one place are one place); of the others, the
    best-first ones at a new place (at least ``apart`` from every place) are added until ``places`` are covered."""
    from pcdet.detector import _places

    centres = np.array([[0, 0, 0], [0.01, 0, 0], [0.02, 0, 0], [0.5, 0, 0], [0.51, 0, 0], [1.0, 0, 0]], float)
    assert _places(centres, [0, 1], [2, 3, 4, 5], 0.1, 3) == [3, 5]  # 2 and 4 lie at places already covered
    assert _places(centres, [0, 1], [2, 3, 4, 5], 0.1, 2) == [3]
    assert _places(centres, [0, 3, 5], [1, 2, 4], 0.1, 3) == []
    assert _places(centres, [0], [1, 2], 0.1, 3) == []  # no other place to take
    assert _places(centres, [0, 1], [2, 3, 4, 5], 0.1, 1, beyond=True) == [3]  # one place more than chosen cover


@pytest.mark.slow
def test_with_targets_candidates_are_refined_at_several_places(tmp_path, library):
    """8 scenes of the six parts among 3 distractors (seed 5), depth only, objects given. A model's best-looking
    raw poses often lie on other objects' faces (the step block's and the bracket's do in scene 5), so its coarse
    and full ICPs, spent on the best-looking poses alone (``refine.places = 0``, no ``retry_places``), all go to
    one wrong place and the object is lost. Spread over 3 places (the default) they reach it: at least 3 instances
    more over the 8 scenes (45 against 39 of 48 measured) and at least 0.9 of them."""
    from pcdet.synth import SynthConfig, synthesize

    ds = BopDataset(synthesize(library, tmp_path / "suite", SynthConfig(scenes=8, objects=6, distractors=3, seed=5)))
    total = sum(len(ds.gt(img)) for img in ds)
    spread = sum(_found_with_targets(ds, library, PipelineConfig(), depth_only=True))
    one = sum(_found_with_targets(ds, library, PipelineConfig().replace(refine={"places": 0, "retry_places": 0}),
                                  depth_only=True))
    assert spread >= one + 3 and spread >= 0.9 * total, (spread, one, total)


def _walk_case(library, monkeypatch, cands, explained, clutter):
    """``Detector._select_targets`` on constructed candidates, so that the case does not hang on a scene's last bits:
    ``cands`` lists (obj_id, score, supported pixels (range)) best first; the global terms (points explained and
    clutter left by each, as index ranges) replace ``global_verify.candidate_terms``'s, which the geometry of a real
    scene gives. Returns the detector and a function of the targets: the kept candidates (indices into ``cands``,
    best first)."""
    import types

    import pcdet.detector as detector_module
    from pcdet.global_verify import GlobalTerms
    from pcdet.grouping import Hypothesis
    from pcdet.refine import RegistrationResult
    from pcdet.verify import Verification

    det = Detector(library)
    index = {m.obj_id: i for i, m in enumerate(library)}
    hyps = [Hypothesis(index[o], np.eye(4), np.zeros(0, np.int64)) for o, _, _ in cands]
    regs = [RegistrationResult(np.eye(4), 1.0, 0.001, 100, 10, True) for _ in cands]
    vers = [Verification(sc, 1.0, 1.0, len(px), len(px), 0, 0, 0.0, np.array(px, np.int64)) for _, sc, px in cands]

    def terms(scene_points, model_points, ratio, *args, **kwargs):
        assert len(model_points) == len(cands)  # every candidate in play is offered to the global set
        return GlobalTerms([np.array(e, np.int64) for e in explained], [np.array(c, np.int64) for c in clutter],
                           np.zeros(len(cands)))

    monkeypatch.setattr(detector_module, "candidate_terms", terms)
    frame = types.SimpleNamespace(depth=np.zeros((480, 640), np.float32))
    scene = types.SimpleNamespace(points=np.zeros((4000, 3)), plane=None, normals=None)

    def kept(targets: dict[int, int]) -> list[int]:
        return det._select_targets(frame, scene, list(range(len(cands))), hyps, regs, vers, targets=targets)

    return det, kept


def test_with_targets_an_object_kept_elsewhere_gets_back_the_better_pose_that_lost_its_pixels(library, monkeypatch):
    """As in scene 2 of the six-part suite (seed 5, on the host where it was found): the step block's true pose (0.88)
    loses its pixels to a better-scoring bracket laid onto it (0.95), and walking by score the step block keeps a
    wrong pose elsewhere (0.75) while the bracket's true pose (0.70) is left out by the bracket's count. No object
    is left short, but a step block that scored better was passed over, so the walk is redone with the set that
    best explains the scene first: the step block's and the bracket's true poses."""
    cands = [(1, 0.95, range(0, 800)),       # 0: bracket laid onto the step block
             (5, 0.88, range(0, 1000)),      # 1: the step block's true pose
             (5, 0.75, range(2000, 2600)),   # 2: the step block elsewhere, on a little clutter
             (1, 0.70, range(3000, 3600))]   # 3: the bracket's true pose
    explained = [range(0, 300), range(0, 1000), range(1000, 1100), range(1500, 2100)]
    clutter = [range(300, 1000), [], [], []]  # the bracket on the step block leaves the rest of it unexplained
    det, kept = _walk_case(library, monkeypatch, cands, explained, clutter)
    from pcdet.verify import resolve_conflicts

    # the situation: by score alone the walk keeps the bracket on the step block and the step block elsewhere
    walk = resolve_conflicts(list(range(4)), [np.array(px) for _, _, px in cands], det.config.verify.conflict_overlap,
                             480 * 640)
    assert walk == [0, 2, 3]
    assert kept({5: 1, 1: 1}) == [1, 3]


def test_with_targets_the_redone_walk_takes_each_object_only_up_to_its_count(library, monkeypatch):
    """As in scene 15 of the seed-99 suite (4 objects, on the host where it was found): the walk is redone (a wrong
    T-joint scoring above the bracket took its pixels, leaving the bracket short), and the set that best explains
    the scene without counts holds two step blocks: the true one (0.90) and one laid where the bracket stands
    (0.41), which explains a few more points than the bracket's pose (0.71). One step block is given, so the
    second would be dropped by the count, but taken into the walk before that it takes the bracket's pixels and the
    bracket is lost. With the counts as caps of the global set (``global_verify.select``), the set leaves the
    bracket its spot: the step block is kept once, and the bracket and the T-joint are kept."""
    from pcdet.global_verify import GlobalTerms, select

    cands = [(6, 0.95, range(3000, 3500)),   # 0: a T-joint laid onto the bracket
             (5, 0.90, range(0, 1000)),      # 1: the step block's true pose
             (1, 0.71, range(3000, 3600)),   # 2: the bracket's pose
             (6, 0.60, range(5000, 5500)),   # 3: the T-joint's true pose
             (5, 0.41, range(3000, 3700))]   # 4: a step block where the bracket stands
    explained = [range(1500, 1700), range(0, 1000), range(1500, 2100), range(2500, 3000), range(1500, 2150)]
    clutter = [range(1700, 2100), [], [], [], []]
    det, kept = _walk_case(library, monkeypatch, cands, explained, clutter)
    v = det.config.verify
    # the situation: without caps the best set holds both step blocks and not the bracket
    t = GlobalTerms([np.array(e, np.int64) for e in explained], [np.array(c, np.int64) for c in clutter],
                    np.zeros(5))
    chosen, _ = select(t, v.duplicate_weight, v.clutter_weight, v.violation_weight)
    assert sorted(chosen) == [1, 3, 4]
    assert kept({6: 1, 5: 1, 1: 1}) == [1, 2, 3]


@pytest.mark.slow
def test_with_targets_an_object_left_short_is_refined_at_more_places(tmp_path, library):
    """8 crowded scenes (``pcdet synth --objects 3 --instances 3 --distractors 3 --seed 2026``), objects given with
    their counts. Where an object given is left without a pose after selection (its full ICPs went to other
    places, as for a step block of scene 3), ``refine.retry_places`` (1) refines its best-looking coarse candidate
    at a new place and selects again: at least 1 instance more over the 8 scenes than with ``retry_places = 0``
    (45 against 43 of 50 measured), and at least 0.85 of them. The retry keeps the output independent of the
    thread count."""
    from pcdet.synth import SynthConfig, synthesize

    ds = BopDataset(synthesize(library, tmp_path / "suite",
                               SynthConfig(scenes=8, objects=3, instances=3, distractors=3, seed=2026)))
    total = sum(len(ds.gt(img)) for img in ds)
    retried = _found_with_targets(ds, library, PipelineConfig())
    once = _found_with_targets(ds, library, PipelineConfig().replace(refine={"retry_places": 0}))
    assert sum(retried) >= sum(once) + 1 and sum(retried) >= 0.85 * total, (retried, once, total)
    img = ds.images[max(range(len(ds)), key=lambda k: retried[k] - once[k])]  # where the retry helped
    one, two = (Detector(library, workers=n).detect(ds.frame(img), ds.targets(img)).detections for n in (1, 2))
    assert [(d.obj_id, d.T_cam_model.tobytes()) for d in one] == [(d.obj_id, d.T_cam_model.tobytes()) for d in two]
