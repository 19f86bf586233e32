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


_KILL_AFTER = """
import os, signal, sys
from pathlib import Path

frames, n = Path(sys.argv[1]), int(sys.argv[2])
replace = os.replace


def replace_then_maybe_die(src, dst, *a, **k):
    replace(src, dst, *a, **k)
    if Path(dst).parent == frames and len(list(frames.glob("*.json"))) >= n:
        os.kill(os.getpid(), signal.SIGKILL)


os.replace = replace_then_maybe_die
sys.argv = ["pcdet"] + sys.argv[3:]
from pcdet.cli import main
main()
"""


def kill_after_frames(args: list[str], out: Path, n: int) -> int:
    """Run ``pcdet ARGS`` (a run into ``out``) in a process that SIGKILLs itself the moment its ``n``-th frame
    file lands in ``out/frames`` (every output goes through an atomic rename, which the process watches), and
    return how many frame files there are then. The kill follows the run's own progress, never a clock, so a
    slow or a fast machine interrupts it at the same frame."""
    import subprocess
    import sys

    frames = out / "frames"
    p = subprocess.run([sys.executable, "-c", _KILL_AFTER, str(frames), str(n), *args], capture_output=True,
                       text=True)
    assert p.returncode == -9, f"the run was not killed (exit {p.returncode}): {p.stderr[-2000:]}"
    return len(list(frames.glob("*.json")))


def _test_helpers(func) -> list:
    """``func`` and the functions of the test suite it calls, at any depth (names its code, or code nested in it,
    looks up among its module's globals)."""
    import types

    seen, todo, out = set(), [func], []
    while todo:
        f = todo.pop()
        if not isinstance(f, types.FunctionType) or f in seen:
            continue
        seen.add(f)
        out.append(f)
        codes, names = [f.__code__], set()
        while codes:
            c = codes.pop()
            names |= set(c.co_names)
            codes += [k for k in c.co_consts if isinstance(k, types.CodeType)]
        for n in names:
            g = f.__globals__.get(n)
            if isinstance(g, types.FunctionType) and g.__module__.startswith("tests"):
                todo.append(g)
    return out


def _reads_shared_data(item) -> bool:
    """Whether a test, a fixture it uses or a helper either calls (at any depth) reads ../shared/data: its source
    calls ``shared(``, names ``SHARED_DATA`` or a path under ``shared/data``."""
    import inspect

    funcs = [getattr(item, "function", None)]
    info = getattr(item, "_fixtureinfo", None)
    for defs in (info.name2fixturedefs.values() if info else []):
        funcs += [d.func for d in defs]
    for f in [h for f in funcs if f is not None for h in _test_helpers(f)]:
        try:
            src = inspect.getsource(f)
        except (OSError, TypeError):
            continue
        if "shared(" in src or "SHARED_DATA" in src or "shared/data" in src:
            return True
    return False


def pytest_collection_modifyitems(config, items):
    """Every test that reads ../shared/data carries ``@pytest.mark.real``, so that ``-m "not real"`` runs without
    the data: a test that reads it unmarked is a collection error naming it."""
    unmarked = [it.nodeid for it in items if _reads_shared_data(it) and it.get_closest_marker("real") is None]
    if unmarked:
        raise pytest.UsageError("tests read ../shared/data without @pytest.mark.real:\n  " + "\n  ".join(unmarked))
