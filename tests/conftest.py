"""Shared fixtures: the shipped models, a small synthetic BOP dataset, and the real data in ../shared/data."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
MODELS = ROOT / "models"
SHARED_DATA = ROOT.parent / "shared" / "data"


@pytest.fixture(autouse=True, scope="session")
def _cache_dir(tmp_path_factory):
    """Model caches go to a fresh folder, so tests never depend on a developer's ~/.cache."""
    import os

    d = tmp_path_factory.mktemp("xdg_cache")
    old = os.environ.get("XDG_CACHE_HOME")
    os.environ["XDG_CACHE_HOME"] = str(d)
    yield d
    if old is None:
        os.environ.pop("XDG_CACHE_HOME", None)
    else:
        os.environ["XDG_CACHE_HOME"] = old


def shared(name: str) -> Path:
    p = SHARED_DATA / name
    if not p.exists():
        pytest.skip(f"real data {p} is absent (it ships in ../shared/data beside the checkout)")
    return p


@pytest.fixture(scope="session")
def library():
    from pcdet.library import ModelLibrary

    return ModelLibrary.from_folder(MODELS)


@pytest.fixture(scope="session")
def synth_small(tmp_path_factory, library):
    """3 synthetic scenes with 3 objects each (seed 11)."""
    from pcdet.synth import SynthConfig, synthesize

    out = tmp_path_factory.mktemp("synth_small")
    return synthesize(library, out, SynthConfig(scenes=3, objects=3, seed=11))


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def random_pose(rng, scale_t=0.1) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    T[:3, 3] = rng.normal(size=3) * scale_t
    return T


def kill_after_frames(cmd: list[str], out: Path, n: int, timeout: float = 180.0) -> int:
    """Start ``cmd`` (a ``pcdet run`` into ``out``), SIGKILL it once ``n`` frame files are in ``out/frames``,
    and return how many were written by then."""
    import signal
    import subprocess
    import time

    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + timeout
    while len(list((out / "frames").glob("*.json"))) < n and time.time() < deadline and p.poll() is None:
        time.sleep(0.05)
    p.send_signal(signal.SIGKILL)
    p.wait()
    return len(list((out / "frames").glob("*.json")))
