"""The per-frame detections JSON (DESIGN.md's layout); the BOP results CSV is in ``io.bop``."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .atomic import atomic_write_text


def detections_json(frame_info: dict, result, pipeline: dict, version: str) -> str:
    """The per-frame detections document of DESIGN.md."""
    doc = {"pcdet_version": version, "frame": frame_info, "pipeline": pipeline,
           "timing_s": {k: round(v, 4) for k, v in result.timing_s.items()},
           "detections": [d.to_dict() for d in result.detections]}
    return json.dumps(doc, indent=1, default=_jsonable)


def write_detections_json(path, frame_info: dict, result, pipeline: dict, version: str) -> Path:
    """Write ``detections_json`` atomically to ``path``."""
    return atomic_write_text(path, detections_json(frame_info, result, pipeline, version))


def _jsonable(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
