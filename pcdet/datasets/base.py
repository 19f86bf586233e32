"""What every recording reader provides: frame references, lazy frames, and optional ground truth."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Protocol, runtime_checkable

import numpy as np

from ..frame import Frame


@dataclass(frozen=True, order=True)
class FrameRef:
    """One frame of a recording: BOP-style ``scene_id`` and ``im_id`` (recordings that are one sequence use
    scene 1 and the frame's position as ``im_id``), and its time stamp in seconds when the format has one."""

    scene_id: int
    im_id: int
    timestamp: float | None = None


@runtime_checkable
class Recording(Protocol):
    """A sequence of depth frames on disk, read lazily.

    format : the reader's registry name; root : the folder; images : every frame, in recording order;
    models_dir : object models that come with the data, or None.
    """

    format: str
    root: Path
    images: list[FrameRef]
    models_dir: Path | None

    @classmethod
    def detect(cls, path: Path) -> bool:
        """Whether ``path`` looks like this format (cheap: file names only)."""

    def frame(self, ref: FrameRef) -> Frame:
        """Load one frame; ``InputError`` / ``FileNotFoundError`` name the bad file."""

    def source(self, ref: FrameRef) -> str:
        """The file a frame is read from, for messages and result files."""

    def targets(self, ref: FrameRef) -> dict[int, int] | None:
        """``{obj_id: count}`` of the objects known to be in a frame, or None when the format has no labels."""

    def camera_poses(self) -> dict[FrameRef, np.ndarray] | None:
        """Ground-truth ``T_world_cam`` (4, 4, m) per frame, or None when the recording has none."""

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[FrameRef]: ...


class SequenceBase:
    """Shared plumbing for single-sequence readers: ``images``, ``len``, ``iter``, no labels, no models."""

    format = ""
    models_dir: Path | None = None

    def __init__(self, root):
        self.root = Path(root)
        if not self.root.is_dir():
            raise FileNotFoundError(f"{self.root}: recording folder not found")
        self.images: list[FrameRef] = []

    def __len__(self) -> int:
        return len(self.images)

    def __iter__(self) -> Iterator[FrameRef]:
        return iter(self.images)

    def targets(self, ref: FrameRef) -> dict[int, int] | None:
        """None: single-sequence formats carry no object labels."""
        return None

    def camera_poses(self) -> dict[FrameRef, np.ndarray] | None:
        """None unless the format's reader overrides it with ground-truth poses."""
        return None


def quaternion_pose(t: np.ndarray, q_xyzw: np.ndarray) -> np.ndarray:
    """4x4 pose from a translation (3,) and a unit quaternion (x, y, z, w)."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(np.asarray(q_xyzw, float)).as_matrix()
    T[:3, 3] = t
    return T
