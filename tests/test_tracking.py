"""Tracking through a synthetic recording: objects stay put in the world frame (the first camera's) to within
5 mm of the ground truth in every frame they are seen in, one track per object, and tracks.json from the CLI."""
import json
import subprocess
import sys

import numpy as np
import pytest

from pcdet.datasets import open_recording
from pcdet.detector import Detector
from pcdet.synth import SynthConfig, synthesize
from pcdet.tracking import Tracker, TrackingConfig


@pytest.fixture(scope="module")
def recording(tmp_path_factory, library):
    """20 frames sweeping 30 deg around 3 objects (the step block, the elbow, the T-joint). A recording whose first
    frame the detector gets right with its seeds 0, 1 and 2 alike, so that the tests on it check one mechanism of
    the tracking each, not one run of RANSAC's draws; how often tracking holds over recordings of other seeds is
    ``test_tracking_holds_over_recordings_of_several_seeds``."""
    return synthesize(library, tmp_path_factory.mktemp("trk"), SynthConfig(scenes=1, objects=3, sequence=20,
                                                                            sweep_deg=30.0, seed=13))


def _truth(rec):
    """Per ground-truth instance: (obj_id, (F, 3) positions in the first camera's frame, one per frame)."""
    refs = list(rec)
    cams = rec.camera_poses()
    W0 = np.linalg.inv(cams[refs[0]])
    out = []
    for k, g0 in enumerate(rec.gt(refs[0])):
        out.append((g0["obj_id"], np.array([(W0 @ cams[r] @ rec.gt(r)[k]["T_cam_model"])[:3, 3] for r in refs])))
    return out


@pytest.mark.slow
def test_objects_stay_within_5mm_of_the_truth_in_every_frame(recording, library):
    rec = open_recording(recording)
    res = Tracker(Detector(library), TrackingConfig(redetect_every=10)).run(rec)
    truth = _truth(rec)
    assert res.modes[0] == "detect" and res.modes.count("track") >= 15
    assert sorted(t.obj_id for t in res.tracks) == sorted(o for o, _ in truth)  # one track per object
    for t in res.tracks:
        pos = next(p for o, p in truth if o == t.obj_id)
        assert len(t.frames) >= 15
        err = [np.linalg.norm(T[:3, 3] - pos[f]) for f, T in zip(t.frames, t.poses)]
        assert max(err) < 0.005, (t.model, max(err))
        # what the last frame reports (results.csv): the mean of the track's views seen from the corrected camera
        last = t.frames[-1]
        d = next(d for d in res.detections[last] if d.obj_id == t.obj_id)
        want = rec.frame(list(rec)[last]).T_input_cam @ np.linalg.inv(res.camera_poses[last]) @ t.T_world_fused
        np.testing.assert_allclose(d.T_cam_model, want, atol=1e-9)
        assert t.fused >= 2


@pytest.mark.slow
def test_tracking_holds_over_recordings_of_several_seeds(tmp_path, library):
    """Recordings of seeds 12-17 made as ``recording`` is (3 objects each, 18 in all): at least 15 of the 18
    objects are followed by one track each, seen in at least 15 of the 20 frames and within 5 mm of the truth in
    every one (16 measured: in seed 12 the first detection is right, yet two tracks, the flange's and the T-joint's,
    stray 12.4 and 8.5 mm from the truth in some frame)."""
    held = 0
    for seed in range(12, 18):
        rec = open_recording(synthesize(library, tmp_path / str(seed), SynthConfig(
            scenes=1, objects=3, sequence=20, sweep_deg=30.0, seed=seed)))
        res = Tracker(Detector(library), TrackingConfig(redetect_every=10)).run(rec)
        for oid, pos in _truth(rec):
            tracks = [t for t in res.tracks if t.obj_id == oid]
            held += len(tracks) == 1 and len(tracks[0].frames) >= 15 and max(
                np.linalg.norm(T[:3, 3] - pos[f]) for f, T in zip(tracks[0].frames, tracks[0].poses)) < 0.005
    assert held >= 15, held


@pytest.mark.slow
def test_a_wrong_map_pose_is_replaced_by_the_next_better_detection(recording, library):
    """A track whose map pose is wrong (the first detection of a part turned the wrong way round, as happens with
    near-symmetric parts): here, after the first frame, one object's map pose is turned 180 degrees about the
    first camera's viewing axis through the object's centre. Tracking from it fails or finds the wrong pose again;
    without ``confirm`` the next full detection (frame 10) must replace the map pose, so that from then on the
    object is within 5 mm of the truth in every frame it is seen in (0.5-1.1 mm measured), and so is its final map
    pose. The code before map poses could be replaced fails: here the T-joint stays up to 10.7 mm off after frame
    10 (on seed 12's recording a second track was started and the first was not seen again)."""
    tr, errors = _track_with_a_flipped_map_pose(recording, library, TrackingConfig(redetect_every=10, confirm=False))
    late = [e for f, e in errors if f >= 10]
    assert len(late) >= 8 and max(late) < 0.005, (tr.model, late)


@pytest.mark.slow
def test_a_new_map_pose_is_confirmed_by_a_detection_on_the_next_frame(recording, library):
    """With ``confirm`` (the default) the frame after a map pose was set runs a full detection, which replaces a
    wrong first map pose at once: the flipped map pose of the test above is replaced in frame 1, and the object
    is within 5 mm of the truth in every frame from then on (0.5-1.4 mm measured; the code before, which waited
    for frame 10, was 10-18 mm off in frames 1-5). The replaced map pose is confirmed in frame 2 alike; from frame
    3 the object is tracked."""
    tr, errors = _track_with_a_flipped_map_pose(recording, library, TrackingConfig(redetect_every=10))
    after = [e for f, e in errors if f >= 1]
    assert len(after) >= 17 and max(after) < 0.005, (tr.model, after)
    assert tr.modes[1:4] == ["detect", "detect", "track"]


@pytest.mark.slow
def test_a_confirming_detection_due_survives_a_checkpoint(recording, library):
    """A tracker restored from its state after the first frame runs the confirming detection on the next frame,
    as the uninterrupted tracker does, with the same result."""
    rec = open_recording(recording)
    refs = list(rec)
    a = Tracker(Detector(library), TrackingConfig(redetect_every=10))
    a.step(rec.frame(refs[0]))
    b = Tracker(Detector(library), TrackingConfig(redetect_every=10))
    b.restore(a.state(None))
    (Ta, mode_a), (Tb, mode_b) = a.step(rec.frame(refs[1])), b.step(rec.frame(refs[1]))
    assert mode_a == mode_b == "detect"
    np.testing.assert_array_equal(Ta, Tb)


def _track_with_a_flipped_map_pose(recording, library, config):
    """Track the recording after turning one object's map pose 180 degrees (after the first frame) about the first
    camera's viewing axis through the object's centre: the track and its (frame, position error in m) pairs."""
    rec = open_recording(recording)
    truth = _truth(rec)
    trk = Tracker(Detector(library), config)
    refs = list(rec)
    trk.step(rec.frame(refs[0]))
    tr = max(trk.tracks, key=lambda t: t.id)  # the last track made (any would do)
    c = tr.T_world_model[:3, :3] @ library[tr.model_index].points.mean(axis=0) + tr.T_world_model[:3, 3]
    flip = np.diag([-1.0, -1.0, 1.0, 1.0])
    flip[:3, 3] = c - flip[:3, :3] @ c  # 180 degrees about the line through c along the first camera's z
    tr.T_world_model = flip @ tr.T_world_model
    for r in refs[1:]:
        trk.step(rec.frame(r))
    pos = next(p for o, p in truth if o == tr.obj_id)
    assert np.linalg.norm(tr.T_world_model[:3, 3] - pos[0]) < 0.005  # the final map pose
    return tr, [(f, np.linalg.norm(T[:3, 3] - pos[f])) for f, T in zip(tr.frames, tr.poses)]


@pytest.fixture(scope="module")
def tracked(recording, tmp_path_factory):
    """``pcdet run --track`` over the whole recording, uninterrupted: its output folder."""
    out = tmp_path_factory.mktemp("tracked") / "out"
    r = subprocess.run([sys.executable, "-m", "pcdet.cli", "run", str(recording), "--out", str(out),
                        "--track", "--redetect-every", "0"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return out


@pytest.mark.slow
def test_cli_track_writes_tracks_json(tracked):
    doc = json.loads((tracked / "tracks.json").read_text())
    (scene,) = doc["scenes"]
    # the first frame, and the next to confirm its map poses
    assert len(scene["camera_poses"]) == 20 and scene["frame_modes"][:2] == ["detect", "detect"]
    assert scene["frame_modes"].count("detect") == 2
    assert {"id", "model", "obj_id", "T_world_model", "observations"} <= set(scene["tracks"][0])


@pytest.mark.slow
def test_tracking_writes_frames_and_a_results_csv_that_eval_scores(recording, tracked):
    """--track writes what detection writes: one frame JSON per frame (mode detect or track) and results.csv
    with camera-frame poses; pcdet eval scores it (measured: recall ADD-S 1.00 over the 60 instances, precision
    1.00; the bar is 0.9 / 0.9)."""
    from typer.testing import CliRunner

    from pcdet.cli import app

    frames = sorted((tracked / "frames").glob("*.json"))
    assert len(frames) == 20
    modes = [json.loads(p.read_text())["frame"]["mode"] for p in frames]
    assert modes[:2] == ["detect", "detect"] and modes[2:] == ["track"] * 18
    rows = (tracked / "results.csv").read_text().splitlines()
    assert rows[0].startswith("scene_id,im_id,obj_id,score,R,t,time") and len(rows) - 1 >= 55
    res = CliRunner().invoke(app, ["eval", str(recording), str(tracked / "results.csv"), "--json",
                                   str(tracked / "eval.json")])
    assert res.exit_code == 0, res.output
    ev = json.loads((tracked / "eval.json").read_text())["overall"]
    assert ev["instances"] == 60 and ev["recall_adds"] >= 0.9 and ev["precision_adds"] >= 0.9, ev


@pytest.mark.slow
def test_killed_tracking_run_resumed_gives_the_same_results(recording, tracked, tmp_path):
    """`pcdet run --track` is killed (SIGKILL) after some frames are written; --resume continues from the last
    checkpoint (odometry, map, tracks) and writes a byte-identical results.csv."""
    from .conftest import kill_after_frames

    out = tmp_path / "out"
    args = ["run", str(recording), "--out", str(out), "--track", "--redetect-every", "0"]
    cmd = [sys.executable, "-m", "pcdet.cli", *args]
    done = kill_after_frames(args, out, 4)
    assert done == 4, f"{done} frames written before the kill, 4 expected"
    assert len(list((out / "tracking_state").glob("*.npz"))) == 1
    assert not (out / "results.csv").exists()
    r = subprocess.run(cmd + ["--resume"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert (out / "results.csv").read_bytes() == (tracked / "results.csv").read_bytes()
    a, b = json.loads((out / "tracks.json").read_text()), json.loads((tracked / "tracks.json").read_text())
    assert a["scenes"][0]["camera_poses"] == b["scenes"][0]["camera_poses"]


@pytest.mark.slow
def test_a_checkpoint_is_plain_data_and_another_version_is_refused_in_one_line(recording, tracked, tmp_path):
    """The tracking checkpoint names no Python class (numpy reads every entry without pickle), so moving or renaming
    one leaves it readable; a checkpoint of another version, or an earlier pcdet's pickled one, stops --resume with
    one ``error:`` line that names the file, never a traceback."""
    import io
    import shutil

    from pcdet.io.checkpoint import VERSION

    ck = tracked / "tracking_state" / "000001.npz"
    data = ck.read_bytes()
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        head = json.loads(str(z["state.json"]))
        assert all(z[k].dtype != object for k in z.files)
    assert head["version"] == VERSION and "pcdet." not in json.dumps(head) and "Track" not in json.dumps(head)
    for case in ("version", "pickled"):
        out = tmp_path / case
        shutil.copytree(tracked, out)
        state = out / "tracking_state" / "000001.npz"
        if case == "version":
            head["version"] = VERSION + 1
            with np.load(io.BytesIO(data), allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files if k != "state.json"}
            buf = io.BytesIO()
            np.savez(buf, **{"state.json": np.array(json.dumps(head))}, **arrays)
            state.write_bytes(buf.getvalue())
            named, words = state, f"a checkpoint of version {VERSION + 1}; this pcdet reads version {VERSION}"
        else:
            state.unlink()
            named = out / "tracking_state" / "000001.pkl"
            named.write_bytes(b"\x80\x04pickled")
            words = "a tracking checkpoint of an earlier pcdet (pickled)"
        r = subprocess.run([sys.executable, "-m", "pcdet.cli", "run", str(recording), "--out", str(out), "--track",
                            "--redetect-every", "0", "--resume"], capture_output=True, text=True)
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert r.returncode != 0 and "Traceback" not in r.stderr, r.stderr
        assert lines[-1].startswith(f"error: {named}: {words}"), r.stderr


@pytest.mark.slow
def test_a_corrupt_frame_is_skipped_and_tracking_goes_on(recording, library, tmp_path):
    import shutil

    rec_dir = tmp_path / "rec"
    shutil.copytree(recording, rec_dir)
    bad = rec_dir / "test" / "000001" / "depth" / "000007.png"
    bad.write_bytes(bad.read_bytes()[:200])
    rec = open_recording(rec_dir)
    res = Tracker(Detector(library), TrackingConfig(redetect_every=10)).run(rec)
    assert res.modes[7].startswith("failed") and "000007.png" in res.modes[7] and res.camera_poses[7] is None
    assert res.modes[8] == "track" and all(len(t.frames) >= 15 for t in res.tracks)
    truth = _truth(rec)
    for t in res.tracks:
        pos = next(p for o, p in truth if o == t.obj_id)
        assert max(np.linalg.norm(T[:3, 3] - pos[f]) for f, T in zip(t.frames, t.poses)) < 0.005


@pytest.mark.real
def test_the_tracker_relocalises_a_camera_beyond_its_icp_reach(library):
    """Every 20th frame of the real 7-Scenes clip (15 frames, steps of up to 20 cm and 14 degrees; none of the
    library's objects is there, so the camera is the odometry's alone): the tracker's frame-to-frame ICP loses the
    camera without the global relocalisation (ATE over 0.1 m; 160 mm measured) and keeps it with it, as `pcdet
    odometry` does (ATE under 40 mm; 25.0 mm measured, against 31.7 mm at every 10th frame, where nothing fires)."""
    from pcdet.odometry import Odometry
    from pcdet.trajectory import ate_rmse

    from .conftest import shared

    rec = open_recording(shared("sevenscenes"))
    refs = list(rec)[::20]
    truth = rec.camera_poses()
    gt = [np.linalg.inv(truth[refs[0]]) @ truth[r] for r in refs]
    frames = [rec.frame(r) for r in refs]
    ate = {}
    for name in ("without", "with"):
        trk = Tracker(Detector(library), TrackingConfig())
        if name == "without":
            trk.odo = Odometry(trk.cfg.odometry)  # no relocalise: the coarse-to-fine ICP alone
        ate[name] = ate_rmse([trk.step(f)[0] for f in frames], gt)
    assert ate["without"] > 0.1 and ate["with"] < 0.04, ate


def test_a_camera_that_turns_an_object_on_its_track_does_not_agree_with_the_map(library):
    """``Tracker._near_tracks``: a detection counts for a camera where it falls on a track of its object in
    position and pose (ADD-S within ``reanchor_distance`` x the diameter), so that a camera that puts an object
    where its track is but turned (the real LINEMOD cat recording: a relocalisation 0.9 m and 87 degrees off the
    truth kept the cat within 0.10 of its diameter of its track) does not keep the camera against the objects. A
    view 2 mm off counts; the same position turned 60 degrees does not; 1.5 diameters off does not."""
    from types import SimpleNamespace

    from pcdet.tracking import Track

    trk = Tracker(Detector(library), TrackingConfig())
    mi = 0
    m = library[mi]
    T_map = _pose([0.3, -0.2, 0.1], [0.05, 0.02, 0.8])
    trk.tracks.append(Track(1, m.name, m.obj_id, mi, T_map))
    det = SimpleNamespace(obj_id=m.obj_id)
    centre = T_map[:3, :3] @ m.points.mean(axis=0) + T_map[:3, 3]
    turn = _pose([0, 0, np.radians(60)], [0, 0, 0])
    turn[:3, 3] = centre - turn[:3, :3] @ centre  # turned about the object's centre: the same position
    near = _pose([0, 0, 0], [0.002, 0, 0])
    far = _pose([0, 0, 0], [1.5 * m.diameter, 0, 0])
    counts = [trk._near_tracks([(det, T @ T_map)], np.eye(4)) for T in (near, turn, far)]
    assert counts == [1, 0, 0], counts


def _pose(rotvec, t):
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def test_a_track_reports_the_running_mean_of_its_views_since_its_map_pose_was_set():
    """``Track.observe``: the fused pose is the mean of the views, translations averaged and the rotation their
    chordal mean (scipy's ``Rotation.mean``, to 1e-9); the map pose stays the first view's; a view that anchors sets
    both and starts the mean again."""
    from scipy.spatial.transform import Rotation

    from pcdet.tracking import Track

    rng = np.random.default_rng(5)
    views = [_pose(0.1 * rng.normal(size=3), [0.1 * i, 0, 0.5]) for i in range(5)]
    tr = Track(1, "part", 1, 0, np.eye(4))
    for i, T in enumerate(views):
        tr.observe(T, anchor=i == 0)
    assert tr.fused == 5
    np.testing.assert_allclose(tr.T_world_fused[:3, 3], [0.2, 0, 0.5], atol=1e-12)
    want = Rotation.from_matrix(np.stack([T[:3, :3] for T in views])).mean().as_matrix()
    np.testing.assert_allclose(tr.T_world_fused[:3, :3], want, atol=1e-9)
    assert np.array_equal(tr.T_world_model, views[0])
    tr.observe(_pose([0, 0.2, 0], [1, 2, 3]), anchor=True)
    assert tr.fused == 1 and np.array_equal(tr.T_world_fused, tr.T_world_model)


@pytest.mark.real
def test_where_tracking_loses_the_camera_the_same_frame_is_detected_and_the_objects_relocalise_it():
    """The last 10 of the 40 real LINEMOD cat frames, each 30 frames of the sequence after the one before (the
    camera moves 30-106 cm and turns 18-98 degrees between them), tracked with the cat's own model: the tracker's
    frame-to-frame odometry does not follow such steps, so the cat is predicted out of view or its refined pose
    fails. Tracking then runs full detection in that same frame, and reports the cat within ADD 0.1 d in at least
    9 of the 10 frames, as detection alone does (10 measured; before, a frame where tracking failed reported
    nothing, and only a loss made the next frame detect: 7 of 10). The detection puts the camera where the mapped
    cat says it is, so the cat keeps one track and the camera stays within 0.1 m of the truth in every frame (62.5
    mm at most measured; before, each detection far from the odometry's guess started a track of its own, 3-4
    tracks, and the camera ended 0.5-1.9 m off)."""
    from pcdet.library import ModelLibrary
    from pcdet.metrics import add

    from .conftest import shared

    data = shared("linemod_cat")
    rec = open_recording(data)
    det = Detector(ModelLibrary.from_folder(data / "models"))
    cat = det.library[det.library.index_of(6)]
    trk = Tracker(det, TrackingConfig())
    found, modes, off = 0, [], []
    T0 = None
    for ref in list(rec)[-10:]:
        T_wc, mode = trk.step(rec.frame(ref))
        modes.append(mode)
        T = next(g["T_cam_model"] for g in rec.gt(ref) if g["obj_id"] == 6)
        T0 = T if T0 is None else T0
        off.append(float(np.linalg.norm(T_wc[:3, 3] - (T0 @ np.linalg.inv(T))[:3, 3])))  # world: the first camera
        found += any(d.obj_id == 6 and add(d.T_cam_model, T, cat.points) < 0.1 * cat.diameter
                     for d in trk.last_detections)
    assert found >= 9 and len(trk.tracks) == 1 and max(off) < 0.1, (found, len(trk.tracks), off, modes)
