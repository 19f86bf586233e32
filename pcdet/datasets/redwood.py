"""The Redwood / 3DMatch layout of Open3D's RGB-D samples: ``depth/*.png`` (mm), ``color/*.jpg``, an Open3D
camera JSON (``intrinsic_matrix``), and optionally camera poses in the log format (``trajectory.log`` or
``odometry.log``: three integers per frame, then the 4x4 ``T_world_cam``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import InputError
from ..io.jsonfile import read_json
from ..io.text import read_text
from .folder import FolderRecording

LOG_NAMES = ("trajectory.log", "odometry.log")


def read_log(path: Path) -> list[np.ndarray]:
    """The 4x4 matrices of a Redwood/3DMatch ``.log`` file, in file order."""
    rows = [line.split() for line in read_text(path, "log file").splitlines() if line.strip()]
    if len(rows) % 5:
        raise InputError(f"{len(rows)} non-empty lines; a log file has 5 per pose (a header and 4 rows)", path)
    poses = []
    for k in range(0, len(rows), 5):
        try:
            poses.append(np.array([[float(x) for x in r] for r in rows[k + 1:k + 5]]))
        except ValueError as e:
            raise InputError(f"pose {k // 5}: {e}", path) from None
        if poses[-1].shape != (4, 4):
            raise InputError(f"pose {k // 5} is not 4x4", path)
    return poses


def _intrinsic_json(root: Path) -> Path | None:
    for p in sorted(root.glob("*.json")):
        try:
            if "intrinsic_matrix" in read_json(p):
                return p
        except InputError:  # some other JSON file: not the intrinsics
            continue
    return None


class RedwoodRecording(FolderRecording):
    """Open3D's RGB-D sample layout (depth/, color/, an intrinsic JSON, optional .log poses) as a recording."""

    format = "redwood"
    colour_dir = "color"

    def __init__(self, root, log: str | None = None):
        super().__init__(root)
        self._gt = None
        names = [log] if log else [n for n in LOG_NAMES if (self.root / n).is_file()]
        if names:
            poses = read_log(self.root / names[0])
            if len(poses) != len(self.images):
                raise InputError(f"{len(poses)} poses for {len(self.images)} depth images", self.root / names[0])
            self._gt = dict(zip(self.images, poses))
            self.log = names[0]

    def _camera(self) -> Camera:
        p = self.root / "camera.json"
        if p.is_file():
            return Camera.from_json(p)
        p = _intrinsic_json(self.root)
        if p is None:
            raise FileNotFoundError(f"{self.root}: no camera JSON (camera.json or an Open3D intrinsic file)")
        return Camera.from_json(p)

    @classmethod
    def detect(cls, path: Path) -> bool:
        """Whether ``path`` has depth/, color/ and an Open3D intrinsic JSON."""
        return (path / "depth").is_dir() and (path / "color").is_dir() and (
            any((path / n).is_file() for n in LOG_NAMES) or _intrinsic_json(path) is not None)

    def camera_poses(self):
        """``T_world_cam`` per frame from the log file, or None without one."""
        return self._gt
