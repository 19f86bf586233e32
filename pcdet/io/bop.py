"""The BOP formats in one place, each reader beside its writer (as bop_toolkit's ``inout`` pairs them):
object poses (``cam_R_m2c`` row-major, ``cam_t_m2c`` in mm), camera poses (``cam_R_w2c``, ``cam_t_w2c``: the
world-to-camera transform, mm), camera entries (``cam_K`` row-major, ``depth_scale`` in mm per raw unit) and
the results CSV (``scene_id,im_id,obj_id,score,R,t,time``: R row-major, t in mm, time in s or -1).
Inside pcdet every pose is a 4 x 4 matrix in metres named by its frames.
"""
from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import atomic_write_text
from .text import read_text

RESULTS_HEADER = ["scene_id", "im_id", "obj_id", "score", "R", "t", "time"]
# Largest max |R R^T - I| of a results row taken for a rotation and re-orthonormalised. BOP's own annotations are
# orthonormal only to about 1e-3 (LM-O's driller: 2e-3, stored to a few decimals); 1e-2 keeps five times that. The
# nearest rotation removes R's symmetric part, whose entries are at most half the deviation, so it moves a point by
# at most 1.5 % of its distance from the model origin (0.3 % at LM-O's 2e-3).
ROTATION_TOLERANCE = 1e-2
# Rows within this of a rotation are taken as written (pcdet writes R to 9 decimals, about 1e-9 off).
ROTATION_EXACT = 1e-6


def nearest_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation nearest to the (3, 3) matrix ``R`` in the Frobenius norm (U V^T of its SVD, det +1)."""
    U, _, Vt = np.linalg.svd(R)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _rt(R, t_mm) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, float).reshape(3, 3)
    T[:3, 3] = np.asarray(t_mm, float) / 1000.0
    return T


def pose_to_bop(T_cam_model: np.ndarray) -> dict:
    """``{"cam_R_m2c": [9], "cam_t_m2c": [3] mm}`` of a (4, 4) pose in metres."""
    return {"cam_R_m2c": T_cam_model[:3, :3].reshape(-1).tolist(), "cam_t_m2c": (T_cam_model[:3, 3] * 1000).tolist()}


def pose_from_bop(entry: dict) -> np.ndarray:
    """(4, 4) ``T_cam_model`` in metres from a ``cam_R_m2c`` / ``cam_t_m2c`` (mm) entry."""
    return _rt(entry["cam_R_m2c"], entry["cam_t_m2c"])


def camera_pose_to_bop(T_world_cam: np.ndarray) -> dict:
    """``{"cam_R_w2c", "cam_t_w2c" (mm)}``: BOP stores the world-to-camera transform, the inverse of
    ``T_world_cam``."""
    T_cw = np.linalg.inv(T_world_cam)
    return {"cam_R_w2c": T_cw[:3, :3].reshape(-1).tolist(), "cam_t_w2c": (T_cw[:3, 3] * 1000).tolist()}


def camera_pose_from_bop(entry: dict) -> np.ndarray:
    """(4, 4) ``T_world_cam`` in metres from a ``cam_R_w2c`` / ``cam_t_w2c`` (mm) entry."""
    return np.linalg.inv(_rt(entry["cam_R_w2c"], entry["cam_t_w2c"]))


def camera_to_bop(K: np.ndarray, depth_scale: float) -> dict:
    """A ``scene_camera.json`` entry: ``cam_K`` (3 x 3, row-major) and ``depth_scale`` (mm per raw unit)."""
    return {"cam_K": np.asarray(K, float).reshape(-1).tolist(), "depth_scale": float(depth_scale)}


def results_row(scene_id: int, im_id: int, obj_id: int, score: float, T_cam_model, time_s: float) -> list[str]:
    """One results CSV row: R row-major to 9 decimals, t in mm to 6, score to 6, time (s) to 3."""
    T = np.asarray(T_cam_model, float)
    R = " ".join(f"{v:.9f}" for v in T[:3, :3].reshape(-1))
    t = " ".join(f"{v * 1000.0:.6f}" for v in T[:3, 3])
    return [str(scene_id), str(im_id), str(obj_id), f"{score:.6f}", R, t, f"{time_s:.3f}"]


def write_results_csv(path, rows: list[list[str]]) -> Path:
    """The header and ``rows`` (as ``results_row`` makes them), written atomically."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(RESULTS_HEADER)
    w.writerows(rows)
    return atomic_write_text(path, buf.getvalue())


def read_results_csv(path) -> list[dict]:
    """Rows as dicts with ``scene_id, im_id, obj_id, score, T_cam_model (4, 4, m), time``, ``line`` (the file
    line) and ``R_deviation`` (max |R R^T - I| of the row as written). An R off a rotation by more than
    ``ROTATION_EXACT`` and at most ``ROTATION_TOLERANCE`` is replaced by its nearest rotation, as real annotations
    need; a row with a non-finite number, a reflection (det R < 0) or an R further from a rotation is refused with
    the file and the line."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: results file not found")
    out = []
    with io.StringIO(read_text(path, "results file"), newline="") as f:
        r = csv.DictReader(f)
        missing = set(RESULTS_HEADER[:6]) - set(r.fieldnames or [])
        if missing:
            raise InputError(f"BOP results CSV lacks column(s) {sorted(missing)}", path)
        for n, row in enumerate(r, start=2):
            short = [k for k in RESULTS_HEADER[:6] if row.get(k) is None]
            if short:
                raise InputError(f"line {n}: the row ends before column(s) {', '.join(short)}; expected "
                                 f"{','.join(RESULTS_HEADER)}", path)
            try:
                R = np.array(row["R"].split(), float).reshape(3, 3)
                t = np.array(row["t"].split(), float).reshape(3)
                score = float(row["score"])
                item = {"scene_id": int(row["scene_id"]), "im_id": int(row["im_id"]), "obj_id": int(row["obj_id"]),
                        "score": score, "T_cam_model": _rt(R, t), "time": float(row.get("time") or -1), "line": n}
            except (ValueError, TypeError, AttributeError) as e:
                raise InputError(f"line {n}: malformed row ({e}); expected scene_id,im_id,obj_id,score, 9 numbers "
                                 "for R, 3 for t (mm), time", path) from None
            if not (np.isfinite(R).all() and np.isfinite(t).all() and np.isfinite(score)):
                raise InputError(f"line {n}: R, t or score is not a finite number", path)
            deviation = float(np.abs(R @ R.T - np.eye(3)).max())
            if deviation > ROTATION_TOLERANCE or np.linalg.det(R) <= 0:
                raise InputError(f"line {n}: R is not a rotation (R R^T differs from I by {deviation:.3g}, det "
                                 f"{np.linalg.det(R):.3g}; up to {ROTATION_TOLERANCE:g} is re-orthonormalised)", path)
            if deviation > ROTATION_EXACT:
                item["T_cam_model"][:3, :3] = nearest_rotation(R)
            item["R_deviation"] = deviation
            out.append(item)
    return out
