"""Readers and writers: depth images, clouds, meshes, detections JSON, BOP CSV."""
from .atomic import atomic_write_bytes, atomic_write_text
from .depth import read_depth_png, read_rgb, write_depth_png

__all__ = ["atomic_write_bytes", "atomic_write_text", "read_depth_png", "read_rgb", "write_depth_png"]
