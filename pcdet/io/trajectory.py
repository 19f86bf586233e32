"""Camera trajectories in the TUM RGB-D format (Sturm et al. 2012): one line per frame,
``timestamp tx ty tz qx qy qz qw``, ``T_world_cam`` (translation in metres, unit quaternion, scalar last).
KISS-ICP, evo and the TUM benchmark tools read and write this format."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InputError
from .atomic import atomic_write_text
from .text import read_text


def format_tum(stamps: list[float], poses: list[np.ndarray]) -> str:
    """The TUM lines for ``poses`` ((4, 4) ``T_world_cam``, m) at ``stamps`` (s, or frame indices)."""
    if len(stamps) != len(poses):
        raise ValueError(f"{len(stamps)} time stamps for {len(poses)} poses")
    lines = ["# timestamp tx ty tz qx qy qz qw  (T_world_cam, metres; the first camera is the world)"]
    for t, T in zip(stamps, poses):
        q = Rotation.from_matrix(T[:3, :3]).as_quat()
        if q[3] < 0:  # one of the two equal quaternions, so that files compare line by line
            q = -q
        vals = [*T[:3, 3], *q]
        lines.append(f"{t:.6f} " + " ".join(f"{v:.9f}" for v in vals))
    return "\n".join(lines) + "\n"


def write_tum(path, stamps: list[float], poses: list[np.ndarray]) -> Path:
    """Write ``poses`` at ``stamps`` to ``path`` in TUM format, atomically."""
    return atomic_write_text(path, format_tum(stamps, poses))


def read_tum(path) -> tuple[list[float], list[np.ndarray]]:
    """(time stamps, (4, 4) poses) from a TUM trajectory file; ``#`` lines are comments. ``InputError`` names the
    file and line of a malformed row."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: trajectory file not found")
    stamps, poses = [], []
    for n, line in enumerate(read_text(path, "trajectory file").splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            v = [float(x) for x in line.split()]
        except ValueError:
            raise InputError(f"line {n}: not numbers", path) from None
        if len(v) != 8 or not np.all(np.isfinite(v)):
            raise InputError(f"line {n}: expected 8 finite numbers (timestamp tx ty tz qx qy qz qw)", path)
        q = np.array(v[4:8])
        if not 0.9 < np.linalg.norm(q) < 1.1:
            raise InputError(f"line {n}: the quaternion is not of unit length", path)
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(q).as_matrix()
        T[:3, 3] = v[1:4]
        stamps.append(v[0])
        poses.append(T)
    return stamps, poses
