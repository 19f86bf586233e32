"""Outputs a user can trust: checked before any work starts, written with the usual permissions, never mixed
between runs (run.json, --resume, --overwrite, a lock), frames written as workers finish them."""
import importlib.util
import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import time

import pytest
from typer.testing import CliRunner

from pcdet.cli import app
from pcdet.errors import InputError
from pcdet.io.outputs import FolderLock, check_file, check_folder

from .conftest import MODELS

runner = CliRunner()


def _cli(*args):
    return runner.invoke(app, [str(a) for a in args])


def _error(res) -> str:
    """The one error line of a failed command (no traceback)."""
    assert res.exit_code != 0, res.output
    assert "Traceback" not in res.output, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert lines[-1].startswith("error:") or any(ln.startswith("error:") for ln in lines), res.output
    return " ".join(lines[[i for i, ln in enumerate(lines) if ln.startswith("error:")][0]:])


@pytest.fixture
def scene(synth_small, tmp_path):
    d = synth_small / "test" / "000001"
    shutil.copy(d / "depth" / "000000.png", tmp_path / "depth.png")
    shutil.copy(synth_small / "camera.json", tmp_path / "cam.json")
    return tmp_path


def test_output_paths_of_the_wrong_kind_or_place_are_refused_first(scene, synth_small):
    """--out that is a folder (for a file), a file (for a folder), or under a file: one error line naming the
    path, before any model is loaded or any frame detected (nothing is written)."""
    base = ["detect", "--models", MODELS, "--depth", scene / "depth.png", "--camera", scene / "cam.json"]
    (scene / "adir").mkdir()
    assert f"{scene / 'adir'}: is a folder, but the detections JSON must be a file" in _error(_cli(*base, "--out",
                                                                                               scene / "adir"))
    (scene / "afile").write_text("x")
    msg = _error(_cli(*base, "--out", scene / "afile" / "det.json"))
    assert "det.json: cannot be written" in msg and "afile is a file" in msg
    # the overlay is checked before the detections JSON is written
    res = _cli(*base, "--out", scene / "ok.json", "--overlay", scene / "adir")
    assert "overlay PNG must be a file" in _error(res) and not (scene / "ok.json").exists()
    assert f"{scene / 'afile'}: is a file, but the output folder must be a folder" in _error(
        _cli("run", synth_small, "--out", scene / "afile"))
    assert "dataset folder must be a folder" in _error(_cli("synth", "--out", scene / "afile", "--scenes", "1"))
    assert "registration JSON must be a file" in _error(_cli("register", MODELS / "obj_000001.ply",
                                                        MODELS / "obj_000002.ply", "--out", scene / "adir"))


def test_check_helpers_create_missing_folders_and_refuse_unwritable_ones(tmp_path):
    assert check_file(tmp_path / "a" / "b" / "f.json") == tmp_path / "a" / "b" / "f.json"
    assert (tmp_path / "a" / "b").is_dir() and not any((tmp_path / "a" / "b").iterdir())
    assert check_folder(tmp_path / "new").is_dir()
    with pytest.raises(InputError, match="cannot be written"):
        check_folder("/proc/pcdet-cannot-be-here")


@pytest.mark.slow
def test_outputs_have_the_usual_permissions(synth_small, tmp_path):
    """Under umask 022 every file pcdet writes is 0644 (the temporary file of an atomic write is 0600)."""
    out = tmp_path / "r"
    code = ("import os, sys; os.umask(0o022); from pcdet.cli import main; "
            "sys.argv = ['pcdet', 'run', sys.argv[1], '--out', sys.argv[2]]; main()")
    p = subprocess.run([sys.executable, "-c", code, str(synth_small), str(out)], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    files = [f for f in out.rglob("*") if f.is_file() and f.name != ".pcdet.lock"]
    assert len(files) >= 6
    assert {oct(stat.S_IMODE(f.stat().st_mode)) for f in files} == {"0o644"}


@pytest.mark.slow
def test_runs_do_not_mix(synth_small, tmp_path):
    """A second run into a folder that holds a run is refused unless --resume (same recording and pipeline
    only) or --overwrite (which removes the old frames first)."""
    out = tmp_path / "r"
    assert _cli("run", synth_small, "--out", out).exit_code == 0
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["format"] == "bop" and manifest["pipeline"]["grouping"]["method"] == "ransac"
    assert "already holds a run (3 frame(s) written)" in _error(_cli("run", synth_small, "--out", out))
    msg = _error(_cli("run", synth_small, "--out", out, "--resume", "--grouping", "gc"))
    assert "--resume: its frames were made differently" in msg and "'ransac' then, 'gc' now" in msg
    res = _cli("run", synth_small, "--out", out, "--resume")
    assert res.exit_code == 0 and "3 kept from before" in res.output.replace("\n", " ")
    (out / "frames" / "000099_000000.json").write_text("{}")  # a stale frame of some other dataset
    assert _cli("run", synth_small, "--out", out, "--overwrite", "--grouping", "gc").exit_code == 0
    assert not (out / "frames" / "000099_000000.json").exists()
    assert json.loads((out / "run.json").read_text())["pipeline"]["grouping"]["method"] == "gc"
    assert "give one of them" in _error(_cli("run", synth_small, "--out", out, "--resume", "--overwrite"))


@pytest.mark.slow
def test_a_folder_in_use_is_refused(synth_small, tmp_path):
    out = tmp_path / "r"
    with FolderLock(out):
        msg = _error(_cli("run", synth_small, "--out", out))
        assert f"another pcdet run (process {os.getpid()}) is writing into this folder" in msg
    assert _cli("run", synth_small, "--out", out).exit_code == 0  # released


def test_synth_into_a_folder_with_scenes_needs_overwrite(library, tmp_path):
    out = tmp_path / "s"
    assert _cli("synth", "--out", out, "--scenes", "2", "--objects", "2", "--seed", "1").exit_code == 0
    assert "already holds 2 scene(s) in test/" in _error(_cli("synth", "--out", out, "--scenes", "1"))
    assert _cli("synth", "--out", out, "--scenes", "1", "--objects", "2", "--overwrite").exit_code == 0
    assert sorted(p.name for p in (out / "test").iterdir()) == ["000001"]


@pytest.mark.slow
def test_worker_processes_write_each_frame_as_it_is_done(library, tmp_path):
    """`pcdet run --workers 2` killed once its first frames are written keeps them; --resume finishes."""
    from pcdet.synth import SynthConfig, synthesize

    rec = synthesize(library, tmp_path / "rec", SynthConfig(scenes=8, objects=2, seed=31))
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "pcdet.cli", "run", str(rec), "--out", str(out), "--workers", "2"]
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 180
    while len(list((out / "frames").glob("*.json"))) < 2 and time.time() < deadline and p.poll() is None:
        time.sleep(0.05)
    os.killpg(p.pid, signal.SIGKILL)
    p.wait()
    done = len(list((out / "frames").glob("*.json")))
    assert 2 <= done < 8, f"{done} frames on disk when the run was killed"
    r = subprocess.run(cmd + ["--resume"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert len(list((out / "frames").glob("*.json"))) == 8


def test_pipeline_values_of_the_wrong_type_name_file_field_and_type(synth_small, tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("[grouping.ransac]\niterations = 10.5\n")
    assert f"{p}: grouping.ransac.iterations = 10.5: expected an integer" in _error(
        _cli("run", synth_small, "--out", tmp_path / "r", "--pipeline", p))
    p.write_text('[preprocess]\nremove_plane = "no"\n')
    assert "preprocess.remove_plane = 'no': expected a boolean" in _error(_cli("config", "dump", "--pipeline", p))


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed")
@pytest.mark.xdist_group("ray")  # one local Ray instance at a time
def test_a_local_ray_instance_listens_on_loopback_only():
    """pcdet's local Ray instance (no --ray-address): every listening socket of every Ray process is on the
    loopback interface, and there is no dashboard. Run in a fresh interpreter, as the CLI would."""
    code = r"""
import ipaddress, psutil
from pcdet.executors import start_local_ray
ray = start_local_ray(1)
ray.get(ray.remote(lambda: 1).remote())
me = psutil.Process()
procs = [me] + me.children(recursive=True)
addrs = set()
for p in procs:
    try:
        addrs |= {c.laddr.ip for c in p.net_connections(kind="inet") if c.status == psutil.CONN_LISTEN}
    except psutil.Error:
        pass
ray.shutdown()
print(sorted(addrs))
bad = [a for a in addrs if not ipaddress.ip_address(a.replace("::ffff:", "")).is_loopback]
assert addrs and not bad, addrs
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=180)
    assert p.returncode == 0, p.stdout + p.stderr
