"""Runs that survive: a killed run resumed equals an uninterrupted one, worker processes do not change the
output, and a corrupt frame in the middle of a recording is reported and skipped."""
import importlib.util
import json
import subprocess
import sys

import numpy as np
import pytest

from pcdet.datasets import open_recording
from pcdet.io.depth import write_depth_png
from pcdet.runner import RunOptions, run_recording
from pcdet.synth import SynthConfig, synthesize

from .conftest import kill_after_frames

# not imported here: pcdet must be the first to import Ray to keep a local instance on loopback
requires_ray = pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed")
# tests that start a local Ray instance run on one xdist worker, one after the other
one_ray = pytest.mark.xdist_group("ray")


@pytest.fixture(scope="module")
def recording(tmp_path_factory, library):
    """A 6-frame synthetic recording (BOP layout, one scene)."""
    return synthesize(library, tmp_path_factory.mktemp("rec"), SynthConfig(scenes=1, objects=3, sequence=6,
                                                                            seed=8))


@pytest.fixture(scope="module")
def uninterrupted(recording, library, tmp_path_factory):
    out = tmp_path_factory.mktemp("full")
    from pcdet.config import PipelineConfig

    s = run_recording(open_recording(recording), library, PipelineConfig(), out)
    assert s.images == 6 and s.detections > 6
    return (out / "results.csv").read_bytes()


@pytest.mark.slow
def test_killed_run_resumed_gives_the_same_results(recording, uninterrupted, tmp_path):
    """`pcdet run` is killed (SIGKILL) after its second frame is written; `--resume` finishes the job."""
    out = tmp_path / "out"
    args = ["run", str(recording), "--out", str(out)]
    cmd = [sys.executable, "-m", "pcdet.cli", *args]
    done = kill_after_frames(args, out, 2)
    assert done == 2, f"{done} frames written before the kill, 2 expected"
    assert not (out / "results.csv").exists()
    r = subprocess.run(cmd + ["--resume"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert f"{done} kept from before" in (r.stdout + r.stderr).replace("\n", " ")
    assert (out / "results.csv").read_bytes() == uninterrupted


@pytest.mark.slow
def test_two_worker_processes_give_the_same_results(recording, uninterrupted, library, tmp_path):
    from pcdet.config import PipelineConfig

    s = run_recording(open_recording(recording), library, PipelineConfig(), tmp_path, RunOptions(workers=2))
    assert s.images == 6
    assert (tmp_path / "results.csv").read_bytes() == uninterrupted


@pytest.mark.slow
def test_corrupt_frame_in_a_plain_folder_recording_is_skipped(recording, library, tmp_path):
    """The recording as depth/ + camera.json with frame 3's PNG truncated: 5 frames written, 1 failure that
    names the file, and the CLI exits 0 with the frame reported."""
    rec = open_recording(recording)
    root = tmp_path / "plain"
    (root / "depth").mkdir(parents=True)
    for ref in rec:
        f = rec.frame(ref)
        write_depth_png(root / "depth" / f"{ref.im_id:03d}.png", np.rint(f.depth * 1000).astype(np.uint16))
    (root / "camera.json").write_text(json.dumps(f.camera.to_dict() | {"depth_scale": 1.0}))
    bad = root / "depth" / "003.png"
    bad.write_bytes(bad.read_bytes()[:300])
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "pcdet.cli", "run", str(root), "--models", str(recording / "models"),
                        "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "skipped scene 1 image 3" in (r.stdout + r.stderr).replace("\n", " ")
    assert len(list((out / "frames").glob("*.json"))) == 5
    failures = json.loads((out / "failures.json").read_text())
    assert len(failures) == 1 and "003.png" in failures[0]["error"]


@pytest.mark.slow
@requires_ray
@one_ray
def test_ray_executor_gives_the_same_results(recording, uninterrupted, library, tmp_path):
    """Detection frames as Ray tasks on a local Ray instance (2 CPUs): the same results.csv, byte for byte."""
    from pcdet.config import PipelineConfig

    s = run_recording(open_recording(recording), library, PipelineConfig(), tmp_path,
                      RunOptions(workers=2, executor="ray"))
    assert s.images == 6
    assert (tmp_path / "results.csv").read_bytes() == uninterrupted


@pytest.mark.slow
@requires_ray
@one_ray
def test_tracking_scenes_spread_over_processes_and_ray_match_one_process(library, tmp_path):
    """Two 5-frame scenes tracked here, on 2 processes, and on Ray: the same tracks and camera poses."""
    from pcdet.config import PipelineConfig
    from pcdet.tracking import track_recording

    rec = open_recording(synthesize(library, tmp_path / "d", SynthConfig(scenes=2, objects=2, sequence=5,
                                                                         sweep_deg=8.0, seed=21)))
    runs = [track_recording(rec, library, PipelineConfig(), workers=w, executor=e)
            for w, e in ((1, "local"), (2, "local"), (2, "ray"))]
    for other in runs[1:]:
        assert other.keys() == runs[0].keys() == {1, 2}
        for sid in runs[0]:
            assert json.dumps(other[sid].to_dict()) == json.dumps(runs[0][sid].to_dict())
    assert all(len(r.tracks) >= 1 for r in runs[0].values())


@pytest.mark.slow
def test_a_frame_that_meets_a_bug_is_reported_and_the_run_goes_on(recording, library, tmp_path, monkeypatch):
    """An unexpected exception while detecting in one frame (here a stage made to raise IndexError on the third
    frame, as ICP of an empty batch of poses once did) is not bad input, but the batch still goes on: the other
    5 frames are written, and failures.json names the frame with an 'internal error' line that gives the type,
    the place in pcdet and the message."""
    from pcdet import detector as det_module
    from pcdet.config import PipelineConfig

    real, calls = det_module.Detector.detect, []

    def detect(self, frame, *a, **k):
        calls.append(1)
        if len(calls) == 3:
            raise IndexError("made to fail")
        return real(self, frame, *a, **k)

    monkeypatch.setattr(det_module.Detector, "detect", detect)
    out = tmp_path / "out"
    s = run_recording(open_recording(recording), library, PipelineConfig(), out)
    assert s.images == 5 and len(list((out / "frames").glob("*.json"))) == 5
    failures = json.loads((out / "failures.json").read_text())
    assert len(failures) == 1, failures
    assert failures[0]["error"].startswith("internal error (please report it): IndexError at pcdet/runner.py:")
    assert "tests/test_runner.py" not in failures[0]["error"] and failures[0]["error"].endswith(": made to fail")
