"""Camera odometry for RGB-D recordings: KISS-ICP (Vizzo et al. 2023) configured for depth-camera range, or
frame-to-frame point-to-plane ICP.

KISS-ICP is made for LiDAR: here it gets metres-scale settings (``OdometryConfig``), no deskewing (a depth image
is taken at one instant) and one thread (its threaded reductions would make the result depend on the thread
count).

Measured with ``python scripts/bench_odometry.py``: on table-top recordings (60 frames, 90 deg) KISS-ICP alone
drifts, because the table is most of every view and point-to-point scan-to-map ICP on a voxel map slides
along it (ATE 74 mm, against 24 mm for repeating the first true motion). Frame-to-frame point-to-plane ICP
holds (2.5 mm). On the 5-frame living-room sample, with walls and furniture at about 2 m, KISS-ICP does well
(2.9 mm) and ICP does better (1.5 mm). The default, ``method = "kiss+icp"``, takes KISS-ICP's pose as the
guess, corrects it by frame-to-frame point-to-plane ICP, and hands the corrected pose back to KISS-ICP
(2.9 mm and 1.6 mm).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np
from scipy.spatial import cKDTree

from .cloud import estimate_normals, voxel_downsample
from .errors import ConfigError
from .frame import Frame
from .refine import RefineConfig, icp


@dataclass(frozen=True)
class OdometryConfig:
    """method: "kiss", "icp" (frame to frame, constant-velocity guess) or "kiss+icp" (KISS-ICP's pose refined
    frame to frame); voxel: KISS-ICP's map voxel (m); min_range / max_range: points used (m); initial_threshold
    and min_motion: KISS-ICP's adaptive threshold start (m) and the motion it ignores (m); icp_voxel:
    frame-to-frame ICP sampling, in metres per metre of the frame's median depth (1 cm at 1 m: a depth
    camera's noise and pixel footprint grow with range); pixel_stride: every n-th pixel row and column is used
    (2 keeps a point every 3.6 mm at 1 m, well under the 1 cm ICP grid, and quarters the work)."""

    method: str = "kiss+icp"
    voxel: float = 0.02
    min_range: float = 0.1
    max_range: float = 4.0
    initial_threshold: float = 0.05
    min_motion: float = 0.005
    icp_voxel: float = 0.01
    pixel_stride: int = 2

    def __post_init__(self):
        if self.method not in ("kiss", "icp", "kiss+icp"):
            raise ConfigError(f"OdometryConfig.method must be 'kiss', 'icp' or 'kiss+icp', got {self.method!r}")


def _kiss(cfg: OdometryConfig):
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    kc = KISSConfig()
    kc.data.deskew = False
    kc.data.max_range = cfg.max_range
    kc.data.min_range = cfg.min_range
    kc.mapping.voxel_size = cfg.voxel
    kc.adaptive_threshold.initial_threshold = cfg.initial_threshold
    kc.adaptive_threshold.min_motion_th = cfg.min_motion
    kc.registration.max_num_threads = 1
    return KissICP(kc)


class _FrameICP:
    """Frame-to-frame point-to-plane ICP: ``step(points, guess)`` returns T_prev_cur. The previous frame is the
    target at ``icp_voxel``; the current frame takes part at twice that spacing (4x fewer points, same fit)."""

    def __init__(self, cfg: OdometryConfig):
        self.cfg = cfg
        self.prev = None

    def step(self, pts: np.ndarray, guess: np.ndarray) -> np.ndarray:
        vox = self.cfg.icp_voxel * float(np.median(pts[:, 2])) if len(pts) else self.cfg.icp_voxel
        p, _, _ = voxel_downsample(pts, vox, representatives=False)
        n = estimate_normals(p, 3 * vox, 30)
        prev, self.prev = self.prev, (p, n, cKDTree(p), vox)
        if prev is None:
            return np.eye(4)
        v = max(vox, prev[3])
        rc = RefineConfig(iterations=40, max_distance=4 * v, kernel=2 * v)
        src, _, _ = voxel_downsample(p, 2 * vox, representatives=False)
        return icp(src, prev[0], prev[1], guess, rc, target_tree=prev[2]).T_target_source


class Odometry:
    """Incremental odometry: ``step(frame)`` returns ``T_first_cam`` (4, 4) of each frame in turn (the first
    is the identity), in the first camera's frame."""

    def __init__(self, cfg: OdometryConfig | None = None):
        self.cfg = cfg = cfg or OdometryConfig()
        self.kiss = _kiss(cfg) if cfg.method in ("kiss", "kiss+icp") else None
        self.f2f = _FrameICP(cfg) if cfg.method in ("icp", "kiss+icp") else None
        self.T = np.eye(4)
        self.last_step = np.eye(4)
        self.gap = 0

    def reset(self, T_first_cam: np.ndarray) -> None:
        """Take ``T_first_cam`` (4, 4) as the current camera pose (a correction from elsewhere, such as tracked
        objects); the next frame is predicted from it."""
        self.T = np.asarray(T_first_cam, float).copy()
        if self.kiss is not None:
            self.kiss.last_pose = self.T.copy()

    def skip(self) -> None:
        """A frame could not be read: the next step predicts two frames' worth of motion (constant velocity)."""
        self.gap += 1

    def step(self, frame: Frame) -> np.ndarray:
        """The next frame's ``T_first_cam`` (4, 4), registering it against the previous one (and KISS-ICP's map)."""
        cfg = self.cfg
        pts, pix = frame.points()
        z = pts[:, 2]
        keep = (z >= cfg.min_range) & (z <= cfg.max_range)
        if cfg.pixel_stride > 1:
            v, u = np.divmod(pix, frame.camera.width)
            keep &= (v % cfg.pixel_stride == 0) & (u % cfg.pixel_stride == 0)
        pts = pts[keep]
        T = self.T
        guess = np.linalg.matrix_power(self.last_step, self.gap + 1)
        if self.kiss is not None:
            if self.gap:
                self.kiss.last_pose = T @ np.linalg.matrix_power(self.last_step, self.gap)
            self.kiss.register_frame(np.ascontiguousarray(pts), np.zeros(len(pts)))
            T_new = self.kiss.last_pose.copy()
            if self.f2f is not None:
                T_new = T @ self.f2f.step(pts, np.linalg.inv(T) @ T_new)
                self.kiss.last_pose = T_new.copy()  # KISS-ICP predicts the next pose from the corrected one
        else:
            T_new = T @ self.f2f.step(pts, guess)
        if not self.gap:  # after a gap the motion spans several frames: keep the per-frame step
            self.last_step = np.linalg.inv(T) @ T_new
        self.gap = 0
        self.T = T_new
        return T_new.copy()


def odometry(frames: Iterable[Frame], cfg: OdometryConfig | None = None) -> Iterator[np.ndarray]:
    """``T_first_cam`` (4, 4) of each frame in turn (the first is the identity), in the first camera's frame."""
    odo = Odometry(cfg)
    for frame in frames:
        yield odo.step(frame)
