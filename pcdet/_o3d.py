"""Import open3d once, quietly, with a clear message when its system library is missing."""
from __future__ import annotations

try:
    import open3d as o3d
except ImportError as e:  # the wheel links libusb-1.0 at import time
    if "libusb" in str(e):
        raise ImportError("open3d needs the system library libusb-1.0-0: run `make setup` or "
                          "`apt-get install libusb-1.0-0`") from e
    raise

o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)

__all__ = ["o3d"]
