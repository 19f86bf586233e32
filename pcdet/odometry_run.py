"""Camera odometry over a whole recording: the trajectory alone, as KISS-ICP's users expect it.

``run_odometry`` steps ``odometry.Odometry`` through every frame of each sequence of a recording (a BOP dataset
with several scenes is one trajectory per scene, each starting at the identity) and returns ``T_world_cam`` per
frame, with the first camera of its sequence as the world. A frame that cannot be read is reported and
skipped; odometry predicts across the gap. ``write_odometry`` writes ``trajectory.txt`` (TUM format; one file
per scene, ``trajectory_<scene>.txt``, when there are several) and ``odometry.toml`` (the resolved config).
"""
from __future__ import annotations

import dataclasses
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .config import toml_value
from .datasets.base import FrameRef
from .errors import InputError, internal_error
from .io.atomic import atomic_write_text
from .io.models import Geometry
from .io.trajectory import write_tum
from .odometry import Odometry, OdometryConfig
from .register import RegistrationWarning, register
from .trajectory import ate_rmse, rpe


@dataclass
class OdometryRun:
    """Per frame ref: ``T_world_cam`` (4, 4, m) of the frames that were read, the seconds each step took, the
    frames that failed (ref, error), and how many frames the odometry recovered (``Odometry.recovered``)."""

    poses: dict[FrameRef, np.ndarray] = field(default_factory=dict)
    seconds: list[float] = field(default_factory=list)
    failed: list[tuple[FrameRef, str]] = field(default_factory=list)
    recovered: int = 0  # frames whose ICP pose fitted badly and a second registration replaced

    @property
    def frames_per_second(self) -> float:
        """Frames per second of odometry alone (frame reading not counted)."""
        return len(self.seconds) / max(sum(self.seconds), 1e-9)


def relocalise(points: np.ndarray, normals: np.ndarray, map_points: np.ndarray,
               map_normals: np.ndarray) -> np.ndarray | None:
    """A camera's ``T_world_cam`` (4, 4) from its points and unit normals (N, 3 each, camera frame, m) on the
    odometry's map's (M, 3 each, world frame, m), with no guess: ``register.register`` (FPFH, RANSAC, ICP), or None
    where it finds no alignment. The odometry's last resort for a frame that fits the map badly
    (``OdometryConfig.recover_below``): on the 7-Scenes clip at every 15th to 30th frame (steps of up to 24 cm and
    19 degrees) the coarse-to-fine ICP alone loses the camera.

    The normals are given as the depth camera saw them (facing it), not left to ``register``, which orients an
    unoriented cloud's normals away from its centroid, as for an object: a room seen from inside gave the frame's
    and the map's normals opposite signs in places, and FPFH then matched the room turned by 180 degrees (the clip
    backwards at every 20th and 25th frame, frames 119 and 124; with the normals facing the camera, 11 of 11
    sampling steps of 5-15 cm register both, against 9 and 6)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RegistrationWarning)  # the odometry judges the fit itself
            return register(Geometry(points, None, normals, 1.0, []),
                            Geometry(map_points, None, map_normals, 1.0, [])).T_target_source
    except InputError:
        return None


def run_odometry(rec, cfg: OdometryConfig | None = None, *,
                 on_frame: Callable[[FrameRef, str | None], None] | None = None) -> OdometryRun:
    """Odometry over every frame of ``rec`` (a ``datasets.Recording``), sequence by sequence (scene by scene).
    ``on_frame(ref, error)`` is called after each frame (error None when it was read)."""
    cfg = cfg or OdometryConfig()
    out = OdometryRun()
    odo, scene = None, None
    for ref in rec:
        if ref.scene_id != scene:
            out.recovered += odo.recovered if odo is not None else 0
            odo, scene = Odometry(cfg, relocalise), ref.scene_id
        try:
            frame = rec.frame(ref)
        except (ValueError, OSError) as e:  # InputError, missing or unreadable files: skip this frame
            odo.skip()
            out.failed.append((ref, str(e)))
            if on_frame:
                on_frame(ref, str(e))
            continue
        t0 = time.perf_counter()
        try:
            out.poses[ref] = odo.step(frame)
        except Exception as e:  # a bug met on this frame: reported, and odometry predicts across it
            odo.skip()
            out.failed.append((ref, internal_error(e)))
            if on_frame:
                on_frame(*out.failed[-1])
            continue
        out.seconds.append(time.perf_counter() - t0)
        if on_frame:
            on_frame(ref, None)
    out.recovered += odo.recovered if odo is not None else 0
    return out


def scenes(run: OdometryRun) -> dict[int, list[FrameRef]]:
    """The frames with a pose, per scene, in recording order."""
    out: dict[int, list[FrameRef]] = {}
    for ref in run.poses:
        out.setdefault(ref.scene_id, []).append(ref)
    return out


def errors_against(run: OdometryRun, truth: dict[FrameRef, np.ndarray]) -> dict[int, tuple[float, float, float]]:
    """Per scene: (ATE m, RPE m, RPE deg) of the run against ground-truth ``T_world_cam``; both trajectories are
    taken relative to the scene's first frame with a pose (frames without truth are left out)."""
    out = {}
    for sid, refs in scenes(run).items():
        refs = [r for r in refs if r in truth]
        if len(refs) < 2:
            continue
        g0, e0 = np.linalg.inv(truth[refs[0]]), np.linalg.inv(run.poses[refs[0]])
        gt = [g0 @ truth[r] for r in refs]
        est = [e0 @ run.poses[r] for r in refs]
        out[sid] = (ate_rmse(est, gt), *rpe(est, gt))
    return out


def write_odometry(folder, run: OdometryRun, cfg: OdometryConfig) -> list[Path]:
    """Write ``trajectory.txt`` (TUM: ``timestamp tx ty tz qx qy qz qw``; the frame's time stamp, or its index
    where the format has none) per scene, and ``odometry.toml``; returns the trajectory files."""
    folder = Path(folder)
    by_scene = scenes(run)
    files = []
    for sid, refs in by_scene.items():
        name = "trajectory.txt" if len(by_scene) == 1 else f"trajectory_{sid:06d}.txt"
        stamps = [r.timestamp if r.timestamp is not None else float(r.im_id) for r in refs]
        files.append(write_tum(folder / name, stamps, [run.poses[r] for r in refs]))
    lines = ["# pcdet odometry: the resolved configuration (OdometryConfig)", "[odometry]"]
    lines += [f"{f.name} = {toml_value(getattr(cfg, f.name))}" for f in dataclasses.fields(cfg)]
    atomic_write_text(folder / "odometry.toml", "\n".join(lines) + "\n")
    return files
