"""pcdet as a package user gets it: a wheel built from this checkout, installed (not editable) into a fresh
environment, runs the demo and finds its presets and sample models from any directory."""
import json
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _run(cmd, **kw):
    p = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=600, **kw)
    assert p.returncode == 0, f"{cmd}\n{p.stdout}\n{p.stderr}"
    return p


@pytest.mark.slow
def test_wheel_installs_and_runs_from_anywhere(tmp_path):
    # build offline with the environment's setuptools: no download while testing
    _run([sys.executable, "-m", "pip", "wheel", "--no-build-isolation", "--no-deps", "-q", "-w", tmp_path / "dist",
          ROOT])
    (wheel,) = (tmp_path / "dist").glob("pcdet-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"pcdet/pipelines/default.toml", "pcdet/pipelines/hough.toml", "pcdet/models/obj_000001.ply",
            "pcdet/models/models_info.json"} <= names
    env_dir = tmp_path / "env"
    _run([sys.executable, "-m", "venv", env_dir])
    py = env_dir / "bin" / "python"
    _run([py, "-m", "pip", "install", "-q", "--no-deps", "--no-index", wheel])
    # the dependencies (open3d, numpy, ...) come from this environment, read-only; pcdet itself from the wheel
    site = Path(_run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    (site / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    where = _run([py, "-c", "import pcdet, pcdet.resources as r; print(pcdet.__file__); print(r.shipped('models'))"],
                 cwd=elsewhere).stdout.split()
    assert all(w.startswith(str(env_dir)) for w in where), where
    pcdet = env_dir / "bin" / "pcdet"
    # the installed package computes what the checkout computes, byte for byte (same code, data and seed)
    _run([pcdet, "demo", "--out", "demo", "--scenes", "1"], cwd=elsewhere)
    _run([sys.executable, "-m", "pcdet.cli", "demo", "--out", tmp_path / "here", "--scenes", "1"], cwd=ROOT)
    assert (elsewhere / "demo" / "overlay.png").read_bytes() == (tmp_path / "here" / "overlay.png").read_bytes()
    results = (elsewhere / "demo" / "run" / "results.csv").read_bytes()
    assert results == (tmp_path / "here" / "run" / "results.csv").read_bytes() and results.count(b"\n") >= 3
    scene = elsewhere / "demo" / "dataset" / "test" / "000001"
    args = ["detect", "--pipeline", "hough", "--depth", scene / "depth" / "000000.png", "--camera",
            scene / "scene_camera.json", "--out"]
    _run([pcdet, *args, "det.json"], cwd=elsewhere)
    _run([sys.executable, "-m", "pcdet.cli", *args, tmp_path / "det_here.json"], cwd=ROOT)
    wheel_doc, here_doc = (json.loads(p.read_text()) for p in (elsewhere / "det.json", tmp_path / "det_here.json"))
    assert wheel_doc["pipeline"]["grouping"]["method"] == "hough" and wheel_doc["detections"]
    assert wheel_doc["detections"] == here_doc["detections"]
