"""The code passes ruff's pycodestyle and pyflakes rules (pyproject.toml's ``[tool.ruff.lint]``): lines within 120
characters, no unused imports or names, no ambiguous names."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_ruff_finds_nothing():
    p = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "pcdet", "scripts", "tests"], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-1000:]
