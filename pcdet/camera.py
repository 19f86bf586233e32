"""Pinhole camera (OpenCV convention: x right, y down, z forward) and back-projection."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .io.jsonfile import read_json


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics in pixels; ``width`` x ``height`` is the image size.

    ``depth_scale`` is millimetres per raw 16-bit depth unit (``raw * depth_scale = mm``), in memory and in
    files alike, as in BOP: 1.0 for Kinect-style PNGs in mm, 0.1 for YCB-Video, 0.2 for TUM RGB-D.
    ``metres_per_unit`` is the same in metres.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    depth_scale: float = 1.0

    def __post_init__(self):
        for name in ("cx", "cy"):
            if not np.isfinite(getattr(self, name)):
                raise InputError(f"camera {name} must be a finite number, got {getattr(self, name)!r}")
        for name in ("fx", "fy"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise InputError(f"camera {name} must be a positive number, got {v!r}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise InputError(f"camera width/height must be positive, got {self.width}x{self.height}")
        if not np.isfinite(self.depth_scale) or self.depth_scale <= 0:
            raise InputError(f"camera depth_scale must be positive, got {self.depth_scale!r}")

    @property
    def metres_per_unit(self) -> float:
        """m per raw depth unit: ``depth_scale`` / 1000."""
        return self.depth_scale / 1000.0

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def to_dict(self) -> dict:
        """The camera as camera.json holds it (``depth_scale`` in mm per raw unit); ``from_dict`` reads it back."""
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
                "width": self.width, "height": self.height, "depth_scale": self.depth_scale}

    @classmethod
    def from_K(cls, K, width: int, height: int, depth_scale: float = 1.0) -> "Camera":
        """A camera from a (3, 3) intrinsic matrix, the image size (pixels) and ``depth_scale`` (mm per raw
        unit)."""
        K = np.asarray(K, dtype=float).reshape(3, 3)
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width), int(height),
                   float(depth_scale))

    @classmethod
    def from_json(cls, path, *, width: int | None = None, height: int | None = None,
                  key: str | None = None) -> "Camera":
        """Read a camera file.

        Accepted layouts: ``{"fx","fy","cx","cy","width","height","depth_scale"}`` (BOP's camera.json);
        one BOP ``scene_camera.json`` entry ``{"cam_K", "depth_scale"}`` or a whole ``scene_camera.json``
        (``{"<im_id>": {...}}``, ``key`` selects the image, default the first); Open3D's
        ``PinholeCameraIntrinsic`` JSON (column-major ``intrinsic_matrix``, depth in mm). As in BOP,
        ``depth_scale`` is millimetres per raw unit (raw * depth_scale = mm; default 1). ``width``/``height``:
        the image size, for files that have none (BOP's cam_K entries); the depth image it belongs to has it.
        """
        data = read_json(path, what="camera file")
        return cls.from_dict(data, path=path, width=width, height=height, key=key)

    @classmethod
    def from_dict(cls, data: dict, *, path=None, width: int | None = None, height: int | None = None,
                  key: str | None = None) -> "Camera":
        """A camera from the parsed JSON of ``from_json`` (``path`` only names the file in errors)."""
        if not isinstance(data, dict):
            raise InputError("camera JSON must be an object", path)
        entries = {k: v for k, v in data.items() if isinstance(v, dict) and "cam_K" in v}
        if "cam_K" not in data and "fx" not in data and "intrinsic_matrix" not in data and entries:
            k = str(key) if key is not None else sorted(entries, key=lambda s: int(s) if s.isdigit() else s)[0]
            if k not in entries:
                raise InputError(f"no camera entry for image {k!r}", path)
            return cls.from_dict(entries[k], path=path, width=width, height=height)
        try:
            if "intrinsic_matrix" in data:
                # Open3D: column-major 3x3; its depth_scale is raw units per metre (default 1000, i.e. mm)
                K = _matrix(data["intrinsic_matrix"]).T
                scale = 1000.0 / float(data.get("depth_scale", 1000.0))
            elif "cam_K" in data:  # one BOP scene_camera entry: depth_scale is mm per raw unit
                K = _matrix(data["cam_K"])
                scale = float(data.get("depth_scale", 1.0))
            elif "fx" in data:  # depth_scale as in BOP: raw * depth_scale = millimetres
                missing = [k for k in ("fx", "fy", "cx", "cy") if k not in data]
                if missing:
                    raise InputError(f"camera JSON lacks {', '.join(missing)} (pcdet's layout has fx, fy, cx, cy, "
                                     "width, height[, depth_scale])", path)
                K = np.array([[float(data["fx"]), 0, float(data["cx"])], [0, float(data["fy"]), float(data["cy"])],
                              [0, 0, 1]])
                scale = float(data.get("depth_scale", 1.0))
            else:
                raise InputError("camera JSON has none of the known layouts: expected fx, fy, cx, cy, width, "
                                 "height[, depth_scale], BOP cam_K[, depth_scale], or Open3D's intrinsic_matrix",
                                 path)
            w, h = data.get("width", width), data.get("height", height)
        except (KeyError, TypeError, ValueError) as e:
            if isinstance(e, InputError):
                raise InputError(e.problem, e.path or path) from None
            raise InputError(f"camera JSON is missing or has a malformed field ({type(e).__name__}: {e}); "
                             "expected fx, fy, cx, cy, width, height[, depth_scale] or BOP cam_K", path) from None
        if w is None or h is None:
            raise InputError("camera JSON gives no image size (width, height), as BOP's cam_K entries do not; "
                             "pcdet takes the size from the depth image when there is one, else add width and "
                             "height", path)
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and float(v).is_integer() for v in (w, h)):
            raise InputError(f"camera width and height must be whole numbers, got {w!r} x {h!r}", path)
        try:
            return cls.from_K(K, int(w), int(h), scale)
        except InputError as e:
            raise InputError(e.problem, path) from None

    def backproject(self, depth: np.ndarray, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Back-project a depth image.

        Parameters
        ----------
        depth : (H, W) float, metres, 0 or non-finite where invalid.
        stride : only every ``stride``-th pixel row and column (from the first) is back-projected.

        Returns
        -------
        points : (N, 3) float64 camera-frame points (m) of the valid pixels, row-major order.
        pixels : (N,) int64 flat pixel indices ``v * W + u`` (of the whole image) of those points.
        """
        depth = np.asarray(depth)
        if depth.shape != (self.height, self.width):
            raise InputError(f"depth image is {depth.shape[1]}x{depth.shape[0]} but the camera is "
                             f"{self.width}x{self.height}")
        if stride < 1:
            raise ValueError(f"stride must be >= 1, got {stride}")
        sub = depth[::stride, ::stride]
        flat = sub.reshape(-1)
        at = np.flatnonzero(np.isfinite(flat) & (flat > 0))
        pixels = at if stride == 1 else (at // sub.shape[1]) * stride * self.width + (at % sub.shape[1]) * stride
        return self.backproject_pixels(pixels, flat[at]), pixels

    def backproject_pixels(self, pixels: np.ndarray, z: np.ndarray) -> np.ndarray:
        """(N,) flat pixel indices ``v * W + u`` with depths ``z`` (N,) m -> (N, 3) float64 camera-frame points."""
        z = np.asarray(z, np.float64)
        v, u = np.divmod(np.asarray(pixels), self.width)
        return np.stack([(u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z], axis=1)

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """(N,) bool: which integer pixel coordinates ``uv`` (N, 2) (u, v) lie inside the image."""
        return (uv[:, 0] >= 0) & (uv[:, 0] < self.width) & (uv[:, 1] >= 0) & (uv[:, 1] < self.height)

    def project(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) camera-frame points (m) -> (N, 2) float pixel coordinates (u, v)."""
        p = np.asarray(points, dtype=float)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.stack([self.fx * p[:, 0] / z + self.cx, self.fy * p[:, 1] / z + self.cy], axis=1)


def _matrix(values) -> np.ndarray:
    """A 3 x 3 float matrix from 9 numbers (a JSON list, row- or column-major as the caller knows)."""
    a = np.asarray(values, dtype=float).reshape(-1)
    if a.size != 9:
        raise InputError(f"a camera matrix needs 9 numbers, got {a.size}")
    return a.reshape(3, 3)
