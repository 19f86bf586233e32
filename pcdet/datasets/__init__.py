"""Recording and dataset readers: one module per format, one Protocol (``base.Recording``), an explicit
registry (``registry.READERS``) with format auto-detection (``open_recording``)."""
from .base import FrameRef, Recording
from .bop import BopDataset
from .registry import READERS, detect_format, open_recording

__all__ = ["BopDataset", "FrameRef", "READERS", "Recording", "detect_format", "open_recording"]
