"""The command line: one clear line and a non-zero exit for bad input; runs that survive bad images;
byte-identical results from two runs (also with a different thread count)."""
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from pcdet.cli import app

from .conftest import MODELS, shared

runner = CliRunner()


def _cli(*args):
    return runner.invoke(app, [str(a) for a in args])


def _error_line(res):
    lines = [ln for ln in res.output.strip().splitlines() if ln.strip()]
    assert res.exit_code != 0, res.output
    assert "Traceback" not in res.output
    assert lines[-1].startswith("error:"), res.output
    return " ".join(lines[lines.index(next(ln for ln in lines if ln.startswith("error:"))):])


@pytest.fixture
def scene(synth_small, tmp_path):
    """One synthetic image as loose files: depth PNG, camera JSON."""
    d = synth_small / "test" / "000001"
    cam = json.loads((synth_small / "camera.json").read_text())
    (tmp_path / "cam.json").write_text(json.dumps(cam))
    shutil.copy(d / "depth" / "000000.png", tmp_path / "depth.png")
    return tmp_path


def test_detect_writes_json_and_overlay(scene):
    res = _cli("detect", "--models", MODELS, "--depth", scene / "depth.png", "--camera", scene / "cam.json",
               "--out", scene / "det.json", "--overlay", scene / "o.png")
    assert res.exit_code == 0, res.output
    doc = json.loads((scene / "det.json").read_text())
    assert set(doc) == {"pcdet_version", "frame", "pipeline", "timing_s", "detections"}
    assert len(doc["detections"]) >= 2
    d = doc["detections"][0]
    assert set(d) == {"model", "obj_id", "score", "T_cam_model", "n_inliers", "group_size", "fitness", "rmse_m",
                      "visible_fraction"}
    assert np.asarray(Image.open(scene / "o.png")).shape == (480, 640, 3)


def test_bad_inputs_one_clear_line(scene):
    base = ["detect", "--models", MODELS, "--out", scene / "x.json"]
    data = (scene / "depth.png").read_bytes()
    (scene / "cut.png").write_bytes(data[: len(data) // 3])
    assert "cut.png: image is truncated" in _error_line(_cli(*base, "--depth", scene / "cut.png", "--camera",
                                                                 scene / "cam.json"))
    Image.fromarray(np.zeros((480, 640), np.uint8)).save(scene / "gray.png")
    assert "gray.png: depth image is L (8-bit" in _error_line(_cli(*base, "--depth", scene / "gray.png",
                                                                   "--camera", scene / "cam.json"))
    Image.fromarray(np.zeros((480, 640, 3), np.uint8)).save(scene / "rgb.png")
    assert "rgb.png: depth image has 3 channels" in _error_line(_cli(*base, "--depth", scene / "rgb.png",
                                                                     "--camera", scene / "cam.json"))
    Image.fromarray(np.full((240, 320), 700, np.uint16)).save(scene / "small.png")
    assert "small.png: depth image is 320x240 but the camera is 640x480" in _error_line(
        _cli(*base, "--depth", scene / "small.png", "--camera", scene / "cam.json"))
    assert "nocam.json: camera file not found" in _error_line(
        _cli(*base, "--depth", scene / "depth.png", "--camera", scene / "nocam.json"))
    (scene / "broken.json").write_text("{fx: 1")
    assert "broken.json: camera file is not valid JSON" in _error_line(
        _cli(*base, "--depth", scene / "depth.png", "--camera", scene / "broken.json"))
    np.savetxt(scene / "nan.xyz", np.full((5, 3), np.nan))
    assert "nan.xyz: point cloud holds no finite point" in _error_line(_cli(*base, "--cloud", scene / "nan.xyz"))


def test_empty_model_file(scene):
    mdir = scene / "models"
    mdir.mkdir()
    (mdir / "empty.ply").write_text("ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    res = _cli("detect", "--models", mdir, "--depth", scene / "depth.png", "--camera", scene / "cam.json",
               "--out", scene / "x.json")
    assert "empty.ply" in _error_line(res)


def test_run_skips_a_corrupt_image_and_writes_the_rest(synth_small, tmp_path):
    ds = tmp_path / "ds"
    shutil.copytree(synth_small, ds)
    bad = ds / "test" / "000002" / "depth" / "000000.png"
    bad.write_bytes(bad.read_bytes()[:500])
    res = _cli("run", ds, "--out", tmp_path / "out")
    assert res.exit_code == 0, res.output
    assert "skipped scene 2 image 0" in res.output
    frames = sorted(p.name for p in (tmp_path / "out" / "frames").glob("*.json"))
    assert frames == ["000001_000000.json", "000003_000000.json"]
    failures = json.loads((tmp_path / "out" / "failures.json").read_text())
    assert len(failures) == 1 and "truncated" in failures[0]["error"]
    rows = (tmp_path / "out" / "results.csv").read_text().splitlines()
    assert rows[0] == "scene_id,im_id,obj_id,score,R,t,time" and len(rows) > 2


def test_run_is_byte_identical_across_runs_and_threads(synth_small, tmp_path):
    outs = []
    for i, threads in enumerate(("1", "2")):
        env = dict(os.environ, OMP_NUM_THREADS=threads, OPENBLAS_NUM_THREADS=threads)
        out = tmp_path / f"run{i}"
        p = subprocess.run([sys.executable, "-m", "pcdet.cli", "run", str(synth_small), "--out", str(out),
                            "--seed", "3"], env=env, capture_output=True, text=True)
        assert p.returncode == 0, p.stderr
        outs.append((out / "results.csv").read_bytes())
    assert outs[0] == outs[1] and outs[0].count(b"\n") > 3


def test_eval_prints_and_writes_json(synth_small, tmp_path):
    assert _cli("run", synth_small, "--out", tmp_path / "r", "--targets", "gt").exit_code == 0
    res = _cli("eval", synth_small, tmp_path / "r" / "results.csv", "--json", tmp_path / "e.json")
    assert res.exit_code == 0, res.output
    ev = json.loads((tmp_path / "e.json").read_text())
    assert ev["overall"]["instances"] == 9 and 0 <= ev["overall"]["recall_add"] <= 1
    assert "ADD-S" in res.output


def test_register_bunny_cli(tmp_path):
    d = shared("bunny")
    res = _cli("register", d / "bun_zipper_res3.ply", d / "bun000.ply", "--out", tmp_path / "T.json")
    assert res.exit_code == 0, res.output
    T = np.array(json.loads((tmp_path / "T.json").read_text())["T_target_source"])
    assert T.shape == (4, 4) and abs(np.linalg.det(T[:3, :3]) - 1) < 1e-6


def test_config_dump_is_valid_toml():
    import tomllib

    res = _cli("config", "dump")
    assert res.exit_code == 0 and tomllib.loads(res.output)["grouping"]["method"] == "ransac"
