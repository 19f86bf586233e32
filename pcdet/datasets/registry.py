"""The readers pcdet knows, in the order auto-detection tries them, and ``open_recording``."""
from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from .bop import BopDataset
from .clouds import CloudFolder
from .folder import FolderRecording
from .redwood import RedwoodRecording
from .sevenscenes import SevenScenesRecording
from .tum import TumRecording

# most specific first: a Redwood folder would also pass as a plain folder if it had camera.json
READERS = {"bop": BopDataset, "tum": TumRecording, "redwood": RedwoodRecording, "7scenes": SevenScenesRecording,
           "folder": FolderRecording, "clouds": CloudFolder}

FORMAT_HELP = ("bop (split/scene/scene_camera.json), tum (rgb.txt + depth.txt), redwood (depth/ + color/ + "
               "Open3D camera JSON or .log poses), 7scenes (frame-XXXXXX.depth.png + .pose.txt, or seq-NN folders of "
               "them), folder (depth/*.png + "
               "camera.json), clouds (*.ply/*.pcd/*.xyz)")


def detect_format(path) -> str:
    """The registry name of the reader whose layout ``path`` has (``InputError`` listing the layouts when none)."""
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: recording folder not found")
    for name, reader in READERS.items():
        if reader.detect(path):
            return name
    raise InputError(f"not a recording pcdet reads; known layouts: {FORMAT_HELP}", path)


def open_recording(path, format: str = "auto"):
    """The reader for ``path``: ``format`` is a key of ``READERS`` or "auto" (detected from file names)."""
    name = detect_format(path) if format == "auto" else format
    if name not in READERS:
        raise InputError(f"unknown recording format {name!r}; known: {', '.join(READERS)}")
    return READERS[name](path)
