"""A plain folder: ``depth/*.png`` (16-bit), optional ``rgb/`` with images of the same stem, ``camera.json``
(any layout ``Camera.from_json`` reads). Frames are taken in file-name order."""
from __future__ import annotations

from pathlib import Path

from ..camera import Camera
from ..errors import InputError
from ..frame import Frame
from ..io.depth import image_size
from .base import FrameRef, SequenceBase

IMAGE_EXTS = (".png", ".jpg", ".jpeg")


def colour_for(folder: Path, stem: str) -> Path | None:
    """The colour image with this stem in ``folder``, if any."""
    for ext in IMAGE_EXTS:
        p = folder / f"{stem}{ext}"
        if p.is_file():
            return p
    return None


class FolderRecording(SequenceBase):
    """depth/*.png with camera.json (and optional rgb/) as a recording, in file-name order (scene 1)."""

    format = "folder"
    colour_dir = "rgb"

    def __init__(self, root):
        super().__init__(root)
        self._depth = sorted((self.root / "depth").glob("*.png"))
        if not self._depth:
            raise InputError("no depth/*.png", self.root)
        self.camera = self._camera()
        self.images = [FrameRef(1, i) for i in range(len(self._depth))]

    def _camera(self) -> Camera:
        """camera.json; when it has no image size (a BOP cam_K entry), the first depth image's."""
        cam = self.root / "camera.json"
        if not cam.is_file():
            raise FileNotFoundError(f"{cam}: camera file not found (a depth folder needs camera.json)")
        w, h = image_size(self._depth[0])
        return Camera.from_json(cam, width=w, height=h)

    @classmethod
    def detect(cls, path: Path) -> bool:
        """Whether ``path`` has depth/ and camera.json."""
        return (path / "depth").is_dir() and (path / "camera.json").is_file()

    def source(self, ref: FrameRef) -> str:
        """The depth PNG of a frame."""
        return str(self._depth[ref.im_id])

    def frame(self, ref: FrameRef) -> Frame:
        """The frame's depth (and colour, when an image of the same stem exists) as a ``Frame``."""
        d = self._depth[ref.im_id]
        rgb = colour_for(self.root / self.colour_dir, d.stem)
        return Frame.from_depth_png(d, self.camera, rgb_path=rgb, info={"scene_id": ref.scene_id,
                                                                        "im_id": ref.im_id})
