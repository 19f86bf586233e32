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
    """20 frames sweeping 30 deg around 3 objects."""
    return synthesize(library, tmp_path_factory.mktemp("trk"), SynthConfig(scenes=1, objects=3, sequence=20,
                                                                            sweep_deg=30.0, seed=12))


def _truth(rec):
    """Per ground-truth instance: (obj_id, (F, 3) positions in the first camera's frame, one per frame)."""
    refs = list(rec)
    cams = rec.camera_poses()
    W0 = np.linalg.inv(cams[refs[0]])
    out = []
    for k, g0 in enumerate(rec.gt(refs[0])):
        out.append((g0["obj_id"], np.array([(W0 @ cams[r] @ rec.gt(r)[k]["T_cam_model"])[:3, 3] for r in refs])))
    return out


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


def test_cli_track_writes_tracks_json(recording, tmp_path):
    r = subprocess.run([sys.executable, "-m", "pcdet.cli", "run", str(recording), "--out", str(tmp_path),
                        "--track", "--redetect-every", "0"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "tracks.json").read_text())
    (scene,) = doc["scenes"]
    assert len(scene["camera_poses"]) == 20 and scene["frame_modes"].count("detect") == 1
    assert {"id", "model", "obj_id", "T_world_model", "observations"} <= set(scene["tracks"][0])


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
