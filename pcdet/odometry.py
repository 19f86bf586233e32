"""Camera odometry for RGB-D recordings: point-to-plane ICP against a map of keyframes (the default),
KISS-ICP (Vizzo et al. 2023) configured for depth-camera range, or KISS-ICP corrected by that ICP.

KISS-ICP is made for LiDAR: here it gets metres-scale settings (``OdometryConfig``), no deskewing (a depth image
is taken at one instant) and one thread (its threaded reductions would make the result depend on the thread
count). Its voxel is 4 cm, its own rule of max range / 100; at 2 cm its scan-to-map search ran at 1 frame/s on
640 x 480 depth frames, and as it ships (1 m) it does not follow a room-scale depth camera.

Measured with ``python scripts/bench_odometry.py --frames 300 --data ../shared/data/sevenscenes`` on 7-Scenes (300
real Kinect frames, KinectFusion poses; 2026-12-07, one run): ATE 19.5 mm at 46.8 frames/s for the default, 27.3 mm
for plain frame-to-frame ICP, 41.7 mm at 4.1 frames/s for KISS-ICP at 4 cm; Open3D's RGB-D odometry (colour +
depth) 24.9 mm at 2.4 frames/s. This host's speed swings by up to two times between hours (15 frames/s for the
default in a slow one). Weighting each
point by its depth noise took the default from 29.4 mm and frame-to-frame ICP from 49.7 mm; a Tukey kernel one map grid
spacing wide instead of two took them from 22.1 and 27.9 mm. On table-top views KISS-ICP
alone drifts, because the table is most of every view and point-to-point ICP slides along it; point-to-plane
ICP holds. A frame that ICP leaves fitting its map badly is registered again (``OdometryConfig.recover_below``):
so the camera is followed at every 10th to 30th 7-Scenes frame, where ICP alone loses it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Iterator

import numpy as np

from .align import transform
from .blas import on_one_blas_thread
from .cloud import estimate_normals, voxel_downsample, voxel_keys
from .errors import ConfigError
from .frame import Frame
from .grid import GridTree
from .params import check_positive
from .refine import RefineConfig, icp

# ICP stops once a step turns less than 3e-5 rad and moves less than 3 um, far below a depth camera's noise: on the
# 300 7-Scenes frames the same ATE as at 1e-5 rad / 1 um (20.9 against 20.8 mm), in 16 iterations a frame on average
# instead of 18; at 1e-4 rad / 10 um (12 iterations) synthetic recordings lost up to 1.4 mm
STOP = (3e-5, 3e-6)
# A frame that fits the map badly after ICP is registered again coarse to fine from the same guess: samples every 8,
# then every 4 grid spacings, each level reaching twice and weighing within half its spacing (20 iterations, stopping
# at 1e-4 rad and 10 um). On the 7-Scenes clip at every 10th and 12th frame (steps up to 14 cm and 8 degrees) this
# follows the camera the single level loses.
RECOVER_LEVELS = (8, 4)

# relocalise(points, normals, map_points, map_normals): the camera's T_world_cam (4, 4) from its points and unit
# normals (N, 3 each, camera frame, m; the normals face the camera) on the map's (M, 3 each, world frame, m; the
# normals face the keyframes' cameras) with no guess, or None where none is found (odometry_run.relocalise)
Relocalise = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], "np.ndarray | None"]


@dataclass(frozen=True)
class OdometryConfig:
    """method: "icp" (point-to-plane ICP against a map of keyframes, constant-velocity guess), "kiss"
    (KISS-ICP) or "kiss+icp" (KISS-ICP's pose corrected by that ICP); voxel: KISS-ICP's map voxel (m; 4 cm is
    KISS-ICP's own rule, max_range / 100: at 2 cm its scan-to-map search makes it run at 1 frame/s on
    640 x 480 depth); min_range / max_range: points used (m); initial_threshold and min_motion: KISS-ICP's
    adaptive threshold start (m) and the motion it ignores (m); icp_voxel: ICP sampling, in metres per metre of
    the frame's median depth (a depth camera's noise and pixel footprint grow with range); pixel_stride: every
    n-th pixel row and column is used (4 keeps a point every 7 mm at 1 m, under the 1.5 cm ICP grid, and
    sixteenths the work); keyframe_distance (m) / keyframe_angle_deg: how far a frame must be, in position or in
    direction, from every keyframe of the map to become one (a camera back where it has been makes none);
    keyframes: at most this many keyframes make the map ICP registers against, the oldest leaving first (1, with
    0 and 0: plain frame-to-frame ICP); depth_weight_power: each point weighs (median depth / its
    depth)^power, the inverse of a structured-light camera's depth noise variance at 4 (0: all alike);
    icp_kernel: width of ICP's Tukey kernel on the point-to-plane residual, in map grid spacings (the grid is
    ``icp_voxel`` times the median depth; ICP pairs points up to 4 spacings apart); recover_below: a frame is
    registered again where ICP leaves less than this share of its weighted samples that have the map within
    ICP's reach lying within one grid spacing of the map's surface: coarse to fine, then (where ``Odometry``
    has a ``relocalise``) with no guess, and the pose that puts most of the frame on the map is kept (0: never).
    Samples with no map within reach do not count: they see ground the map has not seen yet, which says nothing
    of the pose. On the 7-Scenes clip, forwards and backwards, at every frame to every 30th, the share is 0.91
    at the least where ICP held (0.94 with every frame), and 0.18-0.85 where it had lost the camera. (The share
    of all the samples would not tell: played backwards, where the camera turns towards unseen ground, it falls
    to 0.71 between keyframes while ICP holds.)

    Measured with ``python scripts/bench_odometry.py`` (7-Scenes, 300 real Kinect frames): the map of keyframes
    brings frame-to-frame ICP's ATE from 27.3 to 19.5 mm (the map of the last 10 keyframes, each 10 cm or 10
    degrees from the last one, to 20.9-21.6 mm; and 49.7 to 29.4 mm without the depth weights and with a kernel
    of two spacings). The clip makes 19 keyframes, so 50 hold all of it; where the camera comes back, as on a
    synthetic table-top recording going round twice, 50 hold the first round (docs/measurements.md, "A map of the
    places seen")."""

    method: str = "icp"
    voxel: float = 0.04
    min_range: float = 0.1
    max_range: float = 4.0
    initial_threshold: float = 0.05
    min_motion: float = 0.005
    icp_voxel: float = 0.015
    pixel_stride: int = 4
    keyframe_distance: float = 0.1
    keyframe_angle_deg: float = 10.0
    keyframes: int = 50
    depth_weight_power: float = 4.0
    icp_kernel: float = 1.0
    recover_below: float = 0.9

    def __post_init__(self):
        check_positive(self, "icp_kernel")
        if not 0 <= self.recover_below <= 1:
            raise ConfigError(f"OdometryConfig.recover_below must lie in [0, 1], got {self.recover_below}")
        if self.depth_weight_power < 0:
            raise ConfigError(f"OdometryConfig.depth_weight_power must be >= 0, got {self.depth_weight_power}")
        if self.method not in ("kiss", "icp", "kiss+icp"):
            raise ConfigError(f"OdometryConfig.method must be 'kiss', 'icp' or 'kiss+icp', got {self.method!r}")
        if self.pixel_stride < 1:
            raise ConfigError(f"OdometryConfig.pixel_stride must be >= 1, got {self.pixel_stride}")
        if self.keyframes < 1:  # 0 would keep every keyframe (a list's [-0:] is all of it)
            raise ConfigError(f"OdometryConfig.keyframes must be >= 1, got {self.keyframes}")
        if self.keyframe_distance < 0 or self.keyframe_angle_deg < 0:
            raise ConfigError("OdometryConfig.keyframe_distance and keyframe_angle_deg must be >= 0, got "
                              f"{self.keyframe_distance} and {self.keyframe_angle_deg}")


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


class _KeyframeICP:
    """Point-to-plane ICP of each frame against a map of up to ``keyframes`` keyframes:
    ``step(points, T_world_guess)`` returns ``T_world_cam``. A keyframe enters the map at ``icp_voxel`` (per metre
    of its median depth) with its normals; the current frame takes part at twice that spacing. A frame becomes
    a keyframe where it is ``keyframe_distance`` m or ``keyframe_angle_deg`` away from every keyframe of the map
    (0 and 0 with one keyframe: plain frame-to-frame ICP), so the map holds one view per place and direction the
    camera has been, and a camera that comes back registers against its first views of the place instead of
    against views made since, with the drift since in them. Registering against a map that several frames made,
    instead of against the frame before, stops per-frame errors from adding up while the view overlaps."""

    def __init__(self, cfg: OdometryConfig, relocalise: Relocalise | None = None):
        self.cfg = cfg
        self.relocalise = relocalise
        # (points, normals, weights, T_world_cam): the world frame, each point's depth^-depth_weight_power in its
        # keyframe, and the keyframe's camera
        self.keys: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self.map = None  # (points, normals, tree, voxel)
        self._vox: float | None = None  # the grid spacing of the newest keyframe: the map's cells
        self.recovered = 0  # frames whose pose a second registration changed

    def step(self, pts: np.ndarray, T_world_guess: np.ndarray) -> np.ndarray:
        cfg = self.cfg
        vox = cfg.icp_voxel * float(np.median(pts[:, 2])) if len(pts) else cfg.icp_voxel
        if self.map is None:
            self._add_key(pts, vox, np.eye(4))
            return np.eye(4)
        mp, mn, tree, mvox = self.map
        v = max(vox, mvox)
        rc = RefineConfig(iterations=40, max_distance=4 * v, kernel=cfg.icp_kernel * v)
        src, _, _ = voxel_downsample(pts, 2 * vox, representatives=False)
        w = _depth_weights(src, cfg.depth_weight_power)
        T_world_cur = icp(src, mp, mn, T_world_guess, rc, target_tree=tree, weights=w,
                          tolerance=STOP).T_target_source
        if cfg.recover_below > 0 and len(src):
            T_world_cur = self._recover(pts, src, w, (T_world_guess, T_world_cur), vox=vox, v=v, rc=rc)
        if self._new_view(T_world_cur):
            self._add_key(pts, vox, T_world_cur)
        return T_world_cur

    def _new_view(self, T_world_cam: np.ndarray) -> bool:
        """Whether a camera at ``T_world_cam`` (4, 4) is ``keyframe_distance`` or ``keyframe_angle_deg`` away from
        every keyframe of the map: where it is not, the map already holds a view from about there (a camera back
        where it has been makes no keyframe, and the map keeps the first views of the place)."""
        cfg = self.cfg
        K = np.asarray([k[3] for k in self.keys])
        moved = np.linalg.norm(K[:, :3, 3] - T_world_cam[:3, 3], axis=1)
        # the angle of each R_key^T R_cam from its trace, as metrics.rotation_error_deg
        cos = (np.einsum("kij,ij->k", K[:, :3, :3], T_world_cam[:3, :3]) - 1) / 2
        turned = np.degrees(np.arccos(np.clip(cos, -1, 1)))
        return not ((moved < cfg.keyframe_distance) & (turned < cfg.keyframe_angle_deg)).any()

    def _fit(self, src: np.ndarray, w: np.ndarray | None, T: np.ndarray, v: float) -> tuple[float, float]:
        """How ``T`` (4, 4) puts the samples ``src`` (N, 3, camera frame), weighted by ``w`` (N,) or alike, on the
        map: (on, near), the shares of their weight within ``v`` (m) of the map's surface (point to plane) and
        with a map point within ICP's reach of 4 ``v``."""
        mp, mn, tree, _ = self.map
        q = transform(T, src)
        d, i = tree.query(q, distance_upper_bound=4 * v)
        near = np.isfinite(d)
        on = np.zeros(len(q), bool)
        on[near] = np.abs(np.einsum("ij,ij->i", q[near] - mp[i[near]], mn[i[near]])) < v
        w = np.ones(len(q)) if w is None else w
        total = max(w.sum(), 1e-300)
        return float(w[on].sum() / total), float(w[near].sum() / total)

    def _holds(self, fit: tuple[float, float]) -> bool:
        """Whether a pose's ``_fit`` holds: enough of the samples that have the map within reach lie on it."""
        on, near = fit
        return near > 0 and on / near >= self.cfg.recover_below

    def _recover(self, pts, src, w, guesses: tuple[np.ndarray, np.ndarray], *, vox: float, v: float,
                 rc: RefineConfig) -> np.ndarray:
        """The frame's pose (4, 4): ICP's (``guesses[1]``, from ``guesses[0]``) where it holds (``_holds``);
        otherwise, of it, ICP from a coarse-to-fine registration from the same guess (``RECOVER_LEVELS``) and,
        if the better of those does not hold either, ICP from ``relocalise``'s pose, the one that puts most of
        the frame on the map. ``pts``: the frame's points, ``src`` and ``w`` ICP's samples of them and their
        weights; ``vox``: the frame's sampling step, ``v``: the map's grid spacing (m)."""
        cfg = self.cfg
        mp, mn, tree, _ = self.map
        T_guess, first = guesses
        best, best_fit = first, self._fit(src, w, first, v)
        if self._holds(best_fit):
            return first
        T = T_guess
        for level in RECOVER_LEVELS:
            s, _, _ = voxel_downsample(pts, level * vox, representatives=False)
            coarse = RefineConfig(iterations=20, max_distance=2 * level * v, kernel=level / 2 * v)
            T = icp(s, mp, mn, T, coarse, target_tree=tree, weights=_depth_weights(s, cfg.depth_weight_power),
                    tolerance=(1e-4, 1e-5)).T_target_source
        T = icp(src, mp, mn, T, rc, target_tree=tree, weights=w, tolerance=STOP).T_target_source
        fit = self._fit(src, w, T, v)
        if fit[0] > best_fit[0]:
            best, best_fit = T, fit
        if not self._holds(best_fit) and self.relocalise is not None:
            # sampled as a keyframe, normals facing the camera as the map's do, so that the two agree in sign (FPFH
            # tells a surface's two sides apart)
            start = self.relocalise(*_key_samples(pts, vox), mp, mn)
            if start is not None:
                T = icp(src, mp, mn, start, rc, target_tree=tree, weights=w, tolerance=STOP).T_target_source
                fit = self._fit(src, w, T, v)
                if fit[0] > best_fit[0]:
                    best, best_fit = T, fit
        self.recovered += best is not first
        return best

    def correct(self, C: np.ndarray) -> None:
        """The world poses so far were off by ``C`` (4, 4, left-multiplied): move the map with them."""
        if self.map is not None:
            self.keys = [(transform(C, p), n @ C[:3, :3].T, w, C @ T) for p, n, w, T in self.keys]
            self._build()

    def state(self) -> dict:
        """The keyframes (each its points, normals, weights and camera), their grid spacing and the frames
        recovered, as plain data; the map is rebuilt from them (``load_state``) exactly as it was."""
        return {"keyframes": [{"points": p, "normals": n, "weights": w, "T_world_cam": T} for p, n, w, T in self.keys],
                "voxel": self._vox, "recovered": self.recovered}

    def load_state(self, state: dict) -> None:
        self.keys = [(k["points"], k["normals"], k["weights"], k["T_world_cam"]) for k in state["keyframes"]]
        self.recovered = int(state["recovered"])
        self.map, self._vox = None, state["voxel"]
        if self.keys:
            self._build()

    def _add_key(self, pts: np.ndarray, vox: float, T_world_cam: np.ndarray) -> None:
        p, n = _key_samples(pts, vox)
        # not over this frame's median depth as ICP's weights (_depth_weights): a map cell mixes keyframes
        w = np.maximum(p[:, 2], 1e-3) ** -self.cfg.depth_weight_power
        key = (transform(T_world_cam, p), n @ T_world_cam[:3, :3].T, w, T_world_cam)
        self.keys = (self.keys + [key])[-self.cfg.keyframes:]
        self._vox = vox
        self._build()

    def _build(self) -> None:
        """The map: one point and normal per grid cell, the mean of the keyframes' samples in it weighted by their
        depth noise (as a TSDF fuses its views), normals turned to agree with the newest keyframe's."""
        P, N, W = (np.concatenate(a[::-1]) for a in list(zip(*self.keys))[:3])  # the newest keyframe first
        if len(self.keys) > 1:
            _, first, cell = np.unique(voxel_keys(P, self._vox), return_index=True, return_inverse=True)
            order = np.argsort(first)  # cells in the order of their first sample, as the map was before
            rank = np.empty_like(order)
            rank[order] = np.arange(len(order))
            cell = rank[cell.ravel()]
            sign = np.where(np.einsum("ij,ij->i", N, N[first[order]][cell]) < 0, -1.0, 1.0)
            total = np.bincount(cell, W)
            P = np.stack([np.bincount(cell, W * P[:, j]) for j in range(3)], axis=1) / total[:, None]
            N = np.stack([np.bincount(cell, W * sign * N[:, j]) for j in range(3)], axis=1)
            N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)
        self.map = (P, N, GridTree(P), self._vox)


class Odometry:
    """Incremental odometry: ``step(frame)`` returns ``T_first_cam`` (4, 4) of each frame in turn (the first
    is the identity), in the first camera's frame."""

    def __init__(self, cfg: OdometryConfig | None = None, relocalise: Relocalise | None = None):
        self.cfg = cfg = cfg or OdometryConfig()
        self.kiss = _kiss(cfg) if cfg.method in ("kiss", "kiss+icp") else None
        self.f2f = _KeyframeICP(cfg, relocalise) if cfg.method in ("icp", "kiss+icp") else None
        self.T = np.eye(4)
        self.last_step = np.eye(4)
        self.gap = 0

    @property
    def recovered(self) -> int:
        """Frames so far whose ICP pose fitted the map badly and a second registration replaced
        (``OdometryConfig.recover_below``)."""
        return self.f2f.recovered if self.f2f is not None else 0

    def reset(self, T_first_cam: np.ndarray) -> None:
        """Take ``T_first_cam`` (4, 4) as the current camera pose (a correction from elsewhere, such as tracked
        objects); the next frame is predicted from it."""
        T_new = np.asarray(T_first_cam, float).copy()
        if self.f2f is not None:
            self.f2f.correct(T_new @ np.linalg.inv(self.T))
        self.T = T_new
        if self.kiss is not None:
            self.kiss.last_pose = self.T.copy()

    def state(self) -> dict:
        """The pose, the last step, the frames skipped and the keyframe map as plain data (``pcdet.io.checkpoint``);
        ``ValueError`` for KISS-ICP, whose state cannot be saved."""
        if self.kiss is not None:
            raise ValueError("KISS-ICP odometry's state cannot be saved")
        return {"T": self.T, "last_step": self.last_step, "gap": self.gap,
                "map": None if self.f2f is None else self.f2f.state()}

    def load_state(self, state: dict) -> None:
        """Continue from ``state()``: the next step gives what it would have given."""
        self.T, self.last_step, self.gap = state["T"], state["last_step"], int(state["gap"])
        if self.f2f is not None:
            self.f2f.load_state(state["map"])

    def skip(self) -> None:
        """A frame could not be read: the next step predicts two frames' worth of motion (constant velocity)."""
        self.gap += 1

    @on_one_blas_thread
    def step(self, frame: Frame) -> np.ndarray:
        """The next frame's ``T_first_cam`` (4, 4), registering it against the previous one (and KISS-ICP's map).
        BLAS runs on one thread meanwhile (``pcdet.blas``)."""
        cfg = self.cfg
        pts = _points(frame, cfg)
        T = self.T
        guess = np.linalg.matrix_power(self.last_step, self.gap + 1)
        if self.kiss is not None:
            if self.gap:
                self.kiss.last_pose = T @ np.linalg.matrix_power(self.last_step, self.gap)
            self.kiss.register_frame(np.ascontiguousarray(pts), np.zeros(len(pts)))
            T_new = self.kiss.last_pose.copy()
            if self.f2f is not None:
                T_new = self.f2f.step(pts, T_new)
                self.kiss.last_pose = T_new.copy()  # KISS-ICP predicts the next pose from the corrected one
        else:
            T_new = self.f2f.step(pts, T @ guess)
        if not self.gap:  # after a gap the motion spans several frames: keep the per-frame step
            self.last_step = np.linalg.inv(T) @ T_new
        self.gap = 0
        self.T = T_new
        return T_new.copy()


def _key_samples(points: np.ndarray, vox: float) -> tuple[np.ndarray, np.ndarray]:
    """A frame's points (N, 3, camera frame, m) sampled as a keyframe: one per ``vox`` grid cell (M, 3), and their
    unit normals (M, 3) over 3 ``vox``, facing the camera."""
    p, _, _ = voxel_downsample(points, vox, representatives=False)
    return p, estimate_normals(p, 3 * vox, 30)


def _depth_weights(points: np.ndarray, power: float) -> np.ndarray | None:
    """(N,) weight of each camera-frame point (N, 3): (median depth / its depth)^power, or None (all alike) at
    power 0."""
    if not power or not len(points):
        return None
    z = np.maximum(points[:, 2], 1e-3)
    return (float(np.median(z)) / z) ** power


def _points(frame: Frame, cfg: OdometryConfig) -> np.ndarray:
    """(N, 3) camera-frame points (m) of the valid pixels on every ``pixel_stride``-th row and column whose depth
    lies in [min_range, max_range], in row-major order. Only those pixels are back-projected: a 640 x 480 frame at
    stride 4 has a sixteenth of its pixels to convert."""
    pts, _ = frame.points(cfg.pixel_stride)
    return pts[(pts[:, 2] >= cfg.min_range) & (pts[:, 2] <= cfg.max_range)]


def odometry(frames: Iterable[Frame], cfg: OdometryConfig | None = None,
             relocalise: Relocalise | None = None) -> Iterator[np.ndarray]:
    """``T_first_cam`` (4, 4) of each frame in turn (the first is the identity), in the first camera's frame."""
    odo = Odometry(cfg, relocalise)
    for frame in frames:
        yield odo.step(frame)
