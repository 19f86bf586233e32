"""TUM RGB-D recordings (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats): ``rgb.txt`` and
``depth.txt`` list ``timestamp filename``; depth PNGs hold 5000 units per metre; ``groundtruth.txt`` (optional)
lists ``timestamp tx ty tz qx qy qz qw``, the camera's pose in the world (T_world_cam).

Depth frames are paired with the nearest rgb and ground-truth stamps within ``max_dt`` seconds. The camera comes
from ``camera.json`` in the folder when present, else TUM's default intrinsics (fx = fy = 525, cx = 319.5,
cy = 239.5, 640 x 480), which the dataset documents for its ROS default calibration.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import InputError
from ..frame import Frame
from ..io.text import read_text
from .base import FrameRef, SequenceBase, quaternion_pose

TUM_DEFAULT = Camera(525.0, 525.0, 319.5, 239.5, 640, 480, 0.2)  # 5000 units per metre


def read_stamped(path: Path, columns: int) -> list[tuple[float, list[str]]]:
    """Lines ``timestamp v1 .. v{columns-1}`` of a TUM list file; '#' comments and blank lines skipped."""
    out = []
    for n, line in enumerate(read_text(path, "list file").splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) < columns:
            raise InputError(f"line {n} has {len(parts)} fields, expected {columns}", path)
        try:
            out.append((float(parts[0]), parts[1:columns]))
        except ValueError:
            raise InputError(f"line {n}: time stamp {parts[0]!r} is not a number", path) from None
    return out


def nearest(stamps: np.ndarray, t: float, max_dt: float) -> int:
    """Index of the stamp nearest ``t`` within ``max_dt`` s, or -1."""
    if len(stamps) == 0:
        return -1
    i = int(np.argmin(np.abs(stamps - t)))
    return i if abs(stamps[i] - t) <= max_dt else -1


class TumRecording(SequenceBase):
    """A TUM RGB-D recording (depth.txt, rgb.txt, optional groundtruth.txt) as a recording (scene 1)."""

    format = "tum"

    def __init__(self, root, max_dt: float = 0.02):
        super().__init__(root)
        depth_txt = self.root / "depth.txt"
        if not depth_txt.is_file():
            raise InputError("no depth.txt: not a TUM RGB-D recording", self.root)
        self._depth = read_stamped(depth_txt, 2)
        rgb = read_stamped(self.root / "rgb.txt", 2) if (self.root / "rgb.txt").is_file() else []
        rgb_t = np.array([t for t, _ in rgb])
        self._rgb = [rgb[j][1][0] if (j := nearest(rgb_t, t, max_dt)) >= 0 else None for t, _ in self._depth]
        cam = self.root / "camera.json"
        self.camera = Camera.from_json(cam) if cam.is_file() else TUM_DEFAULT
        self.images = [FrameRef(1, i, t) for i, (t, _) in enumerate(self._depth)]
        self._gt = None
        gt = self.root / "groundtruth.txt"
        if gt.is_file():
            rows = read_stamped(gt, 8)
            gt_t = np.array([t for t, _ in rows])
            poses = {}
            for ref in self.images:
                j = nearest(gt_t, ref.timestamp, max_dt)
                if j >= 0:
                    v = np.array(rows[j][1], float)
                    poses[ref] = quaternion_pose(v[:3], v[3:7])
            self._gt = poses

    @classmethod
    def detect(cls, path: Path) -> bool:
        """Whether ``path`` has depth.txt and rgb.txt."""
        return (path / "depth.txt").is_file() and (path / "rgb.txt").is_file()

    def source(self, ref: FrameRef) -> str:
        """The depth PNG of a frame."""
        return str(self.root / self._depth[ref.im_id][1][0])

    def frame(self, ref: FrameRef) -> Frame:
        """The frame as a ``Frame`` (depth / 5000 unless camera.json says otherwise), its time stamp in ``info``."""
        rgb = self._rgb[ref.im_id]
        return Frame.from_depth_png(self.source(ref), self.camera, rgb_path=self.root / rgb if rgb else None,
                                    info={"scene_id": ref.scene_id, "im_id": ref.im_id, "timestamp": ref.timestamp})

    def camera_poses(self):
        """Ground-truth ``T_world_cam`` per frame (nearest stamp within ``max_dt``), or None without
        groundtruth.txt."""
        return self._gt
