"""The 7-Scenes / 3DMatch RGB-D layout (Shotton et al. 2013; Zeng et al. 2017): one sequence per folder,
``frame-XXXXXX.depth.png`` (uint16 millimetres; 0 or 65535 = no reading), ``frame-XXXXXX.color.jpg`` (7-Scenes)
or ``frame-XXXXXX.color.png`` (3DMatch) and ``frame-XXXXXX.pose.txt`` (4x4 camera-to-world, metres), with the
intrinsics in ``camera-intrinsics.txt`` (a 3x3 K) in the folder or its parent; 7-Scenes ships none, so without
that file the Kinect default it documents is used (fx = fy = 585, cx = 320, cy = 240). The image size comes from
the first depth PNG.

The folder given is one sequence (``chess/seq-01``) or a scene whose sequences are its ``seq-NN`` subfolders
(``chess``, as both datasets ship them); sequence NN is then scene NN, each with its own trajectory.

7-Scenes' colour images are not registered to its depth images (the dataset says so); they are loaded as they
are, and nothing in pcdet's odometry uses them.
"""
from __future__ import annotations

import re
from itertools import pairwise
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import InputError
from ..frame import Frame
from ..io.depth import image_size
from ..io.text import read_text
from .base import FrameRef, SequenceBase

FRAME = re.compile(r"^frame-(\d+)\.depth\.png$")
SEQ = re.compile(r"^seq-(\d+)$")
KINECT_K = (585.0, 585.0, 320.0, 240.0)
NO_READING_M = 65.535  # 65535 mm: 7-Scenes' mark for a pixel without depth


def read_matrix(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """A whitespace-separated matrix of ``shape`` from a text file (``InputError`` naming the file otherwise)."""
    try:
        lines = read_text(path, "matrix file").splitlines()
        M = np.array([[float(x) for x in line.split()] for line in lines if line.strip()])
    except ValueError as e:
        raise InputError(f"not a matrix of numbers: {e}", path) from None
    if M.shape != shape:
        raise InputError(f"expected a {shape[0]}x{shape[1]} matrix, found {'x'.join(map(str, M.shape))}", path)
    if not np.all(np.isfinite(M)):
        raise InputError("matrix holds NaN or infinity", path)
    return M


class SevenScenesRecording(SequenceBase):
    """A 7-Scenes / 3DMatch ``seq-NN`` folder as a recording (scene 1, frames in file-number order), or a scene
    folder of such sequences (scene NN for ``seq-NN``, in number order). ``camera`` is the first sequence's."""

    format = "7scenes"

    def __init__(self, root):
        super().__init__(root)
        seqs = [(1, self.root)] if _frame_numbers(self.root) else _sequences(self.root)
        if not seqs:
            raise InputError("no frame-XXXXXX.depth.png here nor in seq-NN folders: not a 7-Scenes recording",
                             self.root)
        self._frames: dict[FrameRef, tuple[Path, int]] = {}
        self._cameras: dict[int, Camera] = {}
        for sid, folder in seqs:
            numbers = _frame_numbers(folder)
            if not numbers:
                raise InputError("no frame-XXXXXX.depth.png in this sequence", folder)
            for i, n in enumerate(numbers):
                ref = FrameRef(sid, i)
                self.images.append(ref)
                self._frames[ref] = (folder, n)
            self._cameras[sid] = _camera(folder, numbers[0])
        self.camera = self._cameras[seqs[0][0]]

    def _path(self, ref: FrameRef, kind: str) -> Path:
        folder, n = self._frames[ref]
        return folder / f"frame-{n:06d}.{kind}"

    @classmethod
    def detect(cls, path: Path) -> bool:
        """Whether ``path`` (or a ``seq-NN`` folder in it) holds ``frame-000000.depth.png``, or any
        frame-N.depth.png and a pose file."""
        return _is_sequence(path) or any(_is_sequence(p) for p in path.iterdir() if p.is_dir() and SEQ.match(p.name))

    def source(self, ref: FrameRef) -> str:
        """The depth PNG of a frame."""
        return str(self._path(ref, "depth.png"))

    def frame(self, ref: FrameRef) -> Frame:
        """The frame (depth in metres, 65535 read as no depth; colour, ``.color.jpg`` or else ``.color.png``, when
        its size matches the depth's)."""
        camera = self._cameras[ref.scene_id]
        rgb = next((p for p in (self._path(ref, "color.jpg"), self._path(ref, "color.png")) if p.is_file()), None)
        if rgb is not None and image_size(rgb) != (camera.width, camera.height):
            rgb = None
        f = Frame.from_depth_png(self.source(ref), camera, rgb_path=rgb,
                                 info={"scene_id": ref.scene_id, "im_id": ref.im_id,
                                       "frame": self._frames[ref][1]})
        f.depth[f.depth >= NO_READING_M - 1e-3] = 0
        return f

    def camera_poses(self):
        """Ground-truth ``T_world_cam`` per frame from the ``.pose.txt`` files, or None when any is missing."""
        paths = [self._path(ref, "pose.txt") for ref in self.images]
        if not all(p.is_file() for p in paths):
            return None
        return {ref: read_matrix(p, (4, 4)) for ref, p in zip(self.images, paths)}


def _frame_numbers(folder: Path) -> list[int]:
    """The numbers N of the ``frame-N.depth.png`` files in ``folder``, ascending."""
    return sorted(int(m.group(1)) for p in folder.iterdir() if (m := FRAME.match(p.name)))


def _is_sequence(path: Path) -> bool:
    """Whether ``path`` holds ``frame-000000.depth.png``, or any frame-N.depth.png and a pose file."""
    if (path / "frame-000000.depth.png").is_file():
        return True
    return any(FRAME.match(p.name) for p in path.glob("frame-*.depth.png")) and any(path.glob("frame-*.pose.txt"))


def _sequences(folder: Path) -> list[tuple[int, Path]]:
    """``(NN, folder)`` of the ``seq-NN`` subfolders, by NN; ``InputError`` when two share a number."""
    found = sorted((int(m.group(1)), p) for p in folder.iterdir() if p.is_dir() and (m := SEQ.match(p.name)))
    for (a, p), (b, q) in pairwise(found):
        if a == b:
            raise InputError(f"{p.name} and {q.name} are both sequence {a}", folder)
    return found


def _camera(folder: Path, first: int) -> Camera:
    """The sequence's camera: ``camera-intrinsics.txt`` in ``folder`` or its parent (else the Kinect default),
    the size of its first depth PNG (``frame-<first>``)."""
    K = None
    for where in (folder, folder.parent):
        p = where / "camera-intrinsics.txt"
        if p.is_file():
            K = read_matrix(p, (3, 3))
            break
    fx, fy, cx, cy = KINECT_K if K is None else (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))
    w, h = image_size(folder / f"frame-{first:06d}.depth.png")
    return Camera(fx, fy, cx, cy, w, h, 1.0)
