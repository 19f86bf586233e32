"""The data that ships with pcdet: the pipeline presets (``pipelines/``) and the sample models (``models/``).

Both folders sit at the top of the repository; pyproject.toml maps them into the package as ``pcdet/pipelines``
and ``pcdet/models``, so a wheel carries them inside ``pcdet``, and an editable install or a source checkout
finds them beside it.
"""
from __future__ import annotations

import importlib.resources
from pathlib import Path

SHIPPED = ("pipelines", "models")


def shipped(name: str) -> Path:
    """The folder of shipped data ``name`` ("pipelines" or "models") as a path on disk: inside the installed
    package (a wheel puts it there), else at the top of the source checkout the package was imported from."""
    if name not in SHIPPED:
        raise ValueError(f"no shipped folder {name!r}; there are {SHIPPED}")
    inside = Path(str(importlib.resources.files("pcdet") / name))
    if inside.is_dir():
        return inside
    return Path(__file__).resolve().parent.parent / name
