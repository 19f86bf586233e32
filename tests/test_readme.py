"""The README runs as written: every ```sh and ```python block, in order, in a folder laid out like the top of
the repository (models/, docs/) with ../shared/data beside it. Commands that use ../shared/data are skipped
when it is absent (reported). The first block is `make demo` / `make test`, the set-up that runs this suite."""
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"


def _blocks():
    text = (ROOT / "README.md").read_text()
    return [(lang, body) for lang, body in re.findall(r"```(sh|python)\n(.*?)```", text, re.S)]


def test_first_block_is_the_set_up():
    lang, body = _blocks()[0]
    assert lang == "sh" and body.split()[:2] == ["make", "demo"] and "make test" in body


@pytest.mark.slow
def test_every_readme_block_runs(tmp_path):
    work = tmp_path / "repo"
    work.mkdir()
    for name in ("models", "docs"):
        (work / name).symlink_to(ROOT / name)
    if SHARED.is_dir():
        (tmp_path / "shared").symlink_to(SHARED)
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    ran, skipped = 0, []
    for lang, body in _blocks()[1:]:
        if lang == "python":
            p = subprocess.run([sys.executable, "-c", body], cwd=work, env=env, capture_output=True, text=True,
                               timeout=600)
            assert p.returncode == 0, f"README python block failed:\n{body}\n{p.stdout}\n{p.stderr}"
            ran += 1
            continue
        for line in body.splitlines():
            cmd = line.split("#")[0].strip()
            if not cmd:
                continue
            if "../shared/data" in cmd and not SHARED.is_dir():
                skipped.append(cmd)
                continue
            p = subprocess.run(["bash", "-c", cmd], cwd=work, env=env, capture_output=True, text=True, timeout=900)
            assert p.returncode == 0, f"README command failed: {cmd}\n{p.stdout[-2000:]}\n{p.stderr[-2000:]}"
            ran += 1
    assert ran >= 20, ran
    if skipped:
        pytest.skip(f"ran {ran} README commands; {len(skipped)} need ../shared/data, which is absent")
