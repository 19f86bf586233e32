"""A folder of point clouds (``*.ply``, ``*.pcd``, ``*.xyz``) in the sensor's frame, one per frame, in file-name
order. Each becomes a ``Frame`` as in ``Frame.from_cloud`` (organized clouds keep their layout)."""
from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from ..frame import Frame
from .base import FrameRef, SequenceBase

CLOUD_EXTS = (".ply", ".pcd", ".xyz")


class CloudFolder(SequenceBase):
    """A folder of point clouds as a recording: one frame per file, in file-name order (scene 1)."""

    format = "clouds"

    def __init__(self, root):
        super().__init__(root)
        self._files = sorted(p for p in self.root.iterdir() if p.suffix.lower() in CLOUD_EXTS)
        if not self._files:
            raise InputError(f"no point clouds ({', '.join(CLOUD_EXTS)})", self.root)
        self.images = [FrameRef(1, i) for i in range(len(self._files))]

    @classmethod
    def detect(cls, path: Path) -> bool:
        """Whether ``path`` holds point-cloud files."""
        return any(p.suffix.lower() in CLOUD_EXTS for p in path.iterdir() if p.is_file())

    def source(self, ref: FrameRef) -> str:
        """The cloud file of a frame."""
        return str(self._files[ref.im_id])

    def frame(self, ref: FrameRef) -> Frame:
        """The cloud as a ``Frame`` (``Frame.from_cloud``)."""
        f = Frame.from_cloud(self._files[ref.im_id])
        f.info.update({"scene_id": ref.scene_id, "im_id": ref.im_id})
        return f
