"""Result files: per-frame detections JSON and BOP results CSV (``scene_id,im_id,obj_id,score,R,t,time``)."""
from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import atomic_write_text

BOP_HEADER = ["scene_id", "im_id", "obj_id", "score", "R", "t", "time"]


def write_bop_csv(path, rows: list[list[str]]) -> Path:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(BOP_HEADER)
    w.writerows(rows)
    return atomic_write_text(path, buf.getvalue())


def read_bop_csv(path) -> list[dict]:
    """Rows as dicts with ``scene_id, im_id, obj_id, score, T_cam_model (4, 4, m), time``."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: results file not found")
    out = []
    with open(path, newline="") as f:
        r = csv.DictReader(f)
        missing = set(BOP_HEADER[:6]) - set(r.fieldnames or [])
        if missing:
            raise InputError(f"BOP results CSV lacks column(s) {sorted(missing)}", path)
        for n, row in enumerate(r, start=2):
            try:
                T = np.eye(4)
                T[:3, :3] = np.array(row["R"].split(), float).reshape(3, 3)
                T[:3, 3] = np.array(row["t"].split(), float) / 1000.0
                out.append({"scene_id": int(row["scene_id"]), "im_id": int(row["im_id"]),
                            "obj_id": int(row["obj_id"]), "score": float(row["score"]), "T_cam_model": T,
                            "time": float(row.get("time") or -1)})
            except (ValueError, TypeError) as e:
                raise InputError(f"line {n}: malformed row ({e})", path) from None
    return out


def detections_json(frame_info: dict, result, pipeline: dict, version: str) -> str:
    """The per-frame detections document of DESIGN.md."""
    doc = {"pcdet_version": version, "frame": frame_info, "pipeline": pipeline,
           "timing_s": {k: round(v, 4) for k, v in result.timing_s.items()},
           "detections": [d.to_dict() for d in result.detections]}
    return json.dumps(doc, indent=1, default=_jsonable)


def write_detections_json(path, frame_info: dict, result, pipeline: dict, version: str) -> Path:
    return atomic_write_text(path, detections_json(frame_info, result, pipeline, version))


def _jsonable(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
