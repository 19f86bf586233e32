"""A depth frame: depth in metres, its camera, optional colour, and where it came from."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .camera import Camera
from .errors import InputError
from .io.clouds import CloudData, read_cloud
from .io.depth import image_size, read_depth_png, read_rgb


@dataclass
class Frame:
    """One view of a scene.

    depth : (H, W) float32 metres, 0 where invalid.
    camera : intrinsics; ``depth.shape == (camera.height, camera.width)``.
    rgb : (H, W, 3) uint8 or None.
    info : ids and source (file names, BOP scene/image ids), copied into result files.
    T_input_cam : (4, 4) pose of the camera in the input's own frame. Identity for depth images; for a point
        cloud stored in the OpenGL convention (y up, z backward, as PCL's Kinect grabber writes), diag(1,-1,-1,1).
        Detections are reported in the input's frame: ``T_input_model = T_input_cam @ T_cam_model``.
    """

    depth: np.ndarray
    camera: Camera
    rgb: np.ndarray | None = None
    info: dict = field(default_factory=dict)
    T_input_cam: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        d = np.asarray(self.depth)
        src = self.info.get("source")
        if d.ndim != 2:
            raise InputError(f"depth must be a 2D array, got shape {d.shape}", src)
        if not np.issubdtype(d.dtype, np.floating):
            raise InputError(f"depth must be float metres, got {d.dtype}; convert raw depth with the camera's "
                             "depth_scale (Frame.from_depth_png does this)", src)
        if d.shape != (self.camera.height, self.camera.width):
            raise InputError(f"depth image is {d.shape[1]}x{d.shape[0]} but the camera is "
                             f"{self.camera.width}x{self.camera.height}", src)
        d = np.where(np.isfinite(d) & (d > 0), d, 0).astype(np.float32)
        self.depth = d

    def __repr__(self) -> str:
        valid = self.depth[self.depth > 0]
        rng = f", depth {valid.min():.2f}..{valid.max():.2f} m" if valid.size else ", no valid depth"
        src = self.info.get("source")
        return (f"Frame({self.camera.width}x{self.camera.height}, {valid.size} valid pixels{rng}"
                f"{', rgb' if self.rgb is not None else ''}{f', source={src!r}' if src else ''})")

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the depth image."""
        return self.depth.shape

    def points(self, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) float64 camera-frame points (m) of valid pixels and their (N,) flat pixel indices; with
        ``stride``, of every ``stride``-th pixel row and column only (``Camera.backproject``)."""
        return self.camera.backproject(self.depth, stride)

    @classmethod
    def from_depth_png(cls, depth_path, camera: Camera | str | Path, rgb_path=None, info: dict | None = None,
                       plausible_m: tuple[float, float] = (0.05, 20.0)) -> "Frame":
        """Read a 16-bit depth PNG, converting raw units with ``camera.depth_scale``. ``camera``: a ``Camera`` or
        a camera JSON file (any layout ``Camera.from_json`` reads; a file without the image size takes it from
        the depth image)."""
        if not isinstance(camera, Camera):
            w, h = image_size(depth_path)
            camera = Camera.from_json(camera, width=w, height=h)
        raw = read_depth_png(depth_path)
        if raw.shape != (camera.height, camera.width):
            raise InputError(f"depth image is {raw.shape[1]}x{raw.shape[0]} but the camera is "
                             f"{camera.width}x{camera.height}", depth_path)
        depth = raw.astype(np.float32) * np.float32(camera.metres_per_unit)
        valid = depth[depth > 0]
        if valid.size == 0:
            raise InputError("depth image holds no valid (non-zero) pixel", depth_path)
        med = float(np.median(valid))
        if not plausible_m[0] <= med <= plausible_m[1]:
            raise InputError(f"median depth is {med:.4g} m with {camera.depth_scale:g} mm per raw unit: "
                             "the camera's depth_scale is probably wrong (it is mm per unit, as in BOP; "
                             "Kinect-style PNGs in mm need 1.0)", depth_path)
        rgb = read_rgb(rgb_path) if rgb_path is not None else None
        if rgb is not None and rgb.shape[:2] != raw.shape:
            raise InputError(f"colour image is {rgb.shape[1]}x{rgb.shape[0]}, depth is {raw.shape[1]}x{raw.shape[0]}",
                             rgb_path)
        meta = {"source": str(depth_path)}
        meta.update(info or {})
        return cls(depth, camera, rgb, meta)

    @classmethod
    def from_cloud(cls, path, camera: Camera | None = None) -> "Frame":
        """A frame from a point cloud in the sensor's frame (z forward, metres): a file (PLY/PCD/XYZ), an (N, 3)
        array, an organized (H, W, 3) array (NaN where there is no point), or an open3d ``PointCloud``.

        An organized cloud (H x W) keeps its layout and its intrinsics are fitted to the points by least
        squares; an unorganized one is z-buffered into a virtual pinhole camera whose pixel pitch matches the
        point spacing, unless ``camera`` is given.
        """
        cd = read_cloud(path, keep_invalid=True) if isinstance(path, (str, Path)) else _cloud_in_memory(path)
        if not isinstance(path, (str, Path)):
            path = "<points>"
        pts = cd.points
        T_input_cam = np.eye(4)
        fin = np.isfinite(pts).all(axis=1)
        if camera is None and np.median(pts[fin, 2]) < 0:
            # OpenGL-style sensor frame (y up, looking down -z): flip into the OpenCV camera convention
            T_input_cam = np.diag([1.0, -1.0, -1.0, 1.0])
            pts = pts * np.array([1.0, -1.0, -1.0])
        finite = np.isfinite(pts).all(axis=1) & (np.nan_to_num(pts[:, 2]) > 0)
        if finite.sum() < 3:
            raise InputError("point cloud has fewer than 3 finite points in front of the sensor (z > 0)", path)
        if camera is None and cd.shape is not None:
            camera = _fit_organized_camera(pts, cd.shape, path)
        elif camera is None:
            camera = _virtual_camera(pts[finite], path)
        depth = _zbuffer(pts[finite], camera)
        rgb = None
        if cd.colors is not None and cd.shape is not None and (camera.height, camera.width) == cd.shape:
            rgb = (np.nan_to_num(cd.colors).reshape(*cd.shape, 3) * 255).clip(0, 255).astype(np.uint8)
        return cls(depth, camera, rgb, {"source": str(path)}, T_input_cam)


def _cloud_in_memory(obj) -> CloudData:
    """CloudData of an (N, 3) or (H, W, 3) array or an open3d PointCloud."""
    if hasattr(obj, "points") and hasattr(obj, "has_colors"):  # open3d PointCloud
        return CloudData(np.asarray(obj.points, float), None,
                         np.asarray(obj.colors, float) if obj.has_colors() else None)
    a = np.asarray(obj, dtype=float)
    if a.ndim == 3 and a.shape[2] == 3:
        return CloudData(a.reshape(-1, 3), shape=a.shape[:2])
    if a.ndim == 2 and a.shape[1] == 3 and len(a):
        return CloudData(a)
    raise InputError(f"points must be an (N, 3) or (H, W, 3) array or an open3d PointCloud, got shape {a.shape}")


def _fit_organized_camera(pts: np.ndarray, shape: tuple[int, int], path) -> Camera:
    h, w = shape
    v, u = np.divmod(np.arange(h * w), w)
    ok = np.isfinite(pts).all(axis=1) & (np.nan_to_num(pts[:, 2]) > 0)
    x, y, z = pts[ok, 0], pts[ok, 1], pts[ok, 2]
    # u = fx * x/z + cx, v = fy * y/z + cy: two independent linear least-squares fits
    A = np.stack([x / z, np.ones(ok.sum())], axis=1)
    (fx, cx), res_u, *_ = np.linalg.lstsq(A, u[ok], rcond=None)
    A = np.stack([y / z, np.ones(ok.sum())], axis=1)
    (fy, cy), res_v, *_ = np.linalg.lstsq(A, v[ok], rcond=None)
    rms = np.sqrt((float(res_u[0]) + float(res_v[0])) / (2 * ok.sum())) if len(res_u) and len(res_v) else 0.0
    if fx <= 0 or fy <= 0 or rms > 2.0:
        raise InputError(f"organized cloud does not fit a pinhole camera (rms {rms:.1f} px); pass a camera", path)
    return Camera(float(fx), float(fy), float(cx), float(cy), w, h)


def _virtual_camera(pts: np.ndarray, path, max_size: int = 1280) -> Camera:
    """A pinhole camera at the origin looking down +z that sees every point of ``pts`` (N, 3) (all with z > 0),
    its pixel pitch about their spacing and its image at most ``max_size`` pixels wide; ``InputError`` naming
    ``path`` when the points' directions x / z, y / z are not finite numbers."""
    from scipy.spatial import cKDTree

    with np.errstate(over="ignore", invalid="ignore"):
        a = pts[:, 0] / pts[:, 2]
        b = pts[:, 1] / pts[:, 2]
    if not (np.isfinite(np.ptp(a)) and np.isfinite(np.ptp(b))):  # a NaN or an infinity makes the span one
        raise InputError("point cloud coordinates out of range (x / z or y / z is not a finite number)", path)
    sample = pts[:: max(1, len(pts) // 2000)]
    spacing = float(np.median(cKDTree(pts).query(sample, k=2)[0][:, 1]))
    f = float(np.median(pts[:, 2])) / max(spacing, 1e-6)
    span = max(np.ptp(a), np.ptp(b), 1e-6)
    f = min(f, (max_size - 4) / span)
    w = int(np.ceil(np.ptp(a) * f)) + 4
    h = int(np.ceil(np.ptp(b) * f)) + 4
    return Camera(f, f, float(2 - a.min() * f), float(2 - b.min() * f), w, h)


def _zbuffer(pts: np.ndarray, camera: Camera) -> np.ndarray:
    uv = np.rint(camera.project(pts)).astype(np.int64)
    ok = camera.in_image(uv)
    depth = np.full(camera.height * camera.width, np.inf)
    np.minimum.at(depth, uv[ok, 1] * camera.width + uv[ok, 0], pts[ok, 2])
    depth[~np.isfinite(depth)] = 0
    return depth.reshape(camera.height, camera.width).astype(np.float32)
