"""Point-cloud files (PLY, PCD, XYZ/PTS/TXT) to numpy, keeping organisation when the file has it."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

CLOUD_SUFFIXES = {".ply", ".pcd", ".xyz", ".xyzn", ".pts", ".txt"}


@dataclass
class CloudData:
    """Points as read from a file.

    points : (N, 3) float64, as stored (may hold NaN for organized clouds).
    normals : (N, 3) float64 or None.
    colors : (N, 3) float64 in [0, 1] or None.
    shape : (H, W) when the file is organized (N == H * W), else None.
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    shape: tuple[int, int] | None = None


def _pcd_shape(path: Path) -> tuple[int, int] | None:
    width = height = None
    with open(path, "rb") as f:
        for _ in range(20):
            line = f.readline().decode("ascii", "replace").split()
            if not line:
                continue
            if line[0] == "WIDTH":
                width = int(line[1])
            elif line[0] == "HEIGHT":
                height = int(line[1])
            elif line[0] == "DATA":
                break
    if width and height and height > 1:
        return height, width
    return None


def read_cloud(path, keep_invalid: bool = False) -> CloudData:
    """Read a point cloud file.

    Non-finite points are dropped unless ``keep_invalid`` (then an organized cloud keeps its H x W layout).
    Raises ``InputError`` when the file holds no finite point.
    """
    from .._o3d import o3d

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: point cloud not found")
    suffix = path.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise InputError(f"unknown point-cloud format {suffix!r}; expected one of {sorted(CLOUD_SUFFIXES)}", path)
    shape = None
    if path.stat().st_size == 0:
        raise InputError("point cloud is empty (0 bytes)", path)
    if suffix in (".xyz", ".xyzn", ".pts", ".txt"):
        try:
            a = np.loadtxt(path, ndmin=2, dtype=float)
        except ValueError as e:
            raise InputError(f"cannot parse as whitespace-separated numbers ({e})", path) from None
        if a.size == 0:
            raise InputError("point cloud is empty", path)
        if a.shape[1] < 3:
            raise InputError(f"expected at least 3 columns (x y z), got {a.shape[1]}", path)
        pts = a[:, :3]
        nrm = a[:, 3:6] if a.shape[1] >= 6 else None
        col = None
    else:
        pc = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
        pts = np.asarray(pc.points, dtype=np.float64)
        if len(pts) == 0:
            raise InputError("point cloud is empty or could not be parsed", path)
        nrm = np.asarray(pc.normals, dtype=np.float64) if pc.has_normals() else None
        col = np.asarray(pc.colors, dtype=np.float64) if pc.has_colors() else None
        if suffix == ".pcd":
            shape = _pcd_shape(path)
            if shape and shape[0] * shape[1] != len(pts):
                shape = None
    finite = np.isfinite(pts).all(axis=1)
    if nrm is not None:
        nrm = np.where(np.isfinite(nrm), nrm, 0.0)
    if not finite.any():
        raise InputError("point cloud holds no finite point", path)
    if not keep_invalid and not finite.all():
        pts, shape = pts[finite], None
        nrm = nrm[finite] if nrm is not None else None
        col = col[finite] if col is not None else None
    return CloudData(pts, nrm, col, shape)
