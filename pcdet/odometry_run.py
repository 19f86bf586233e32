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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .config import toml_value
from .datasets.base import FrameRef
from .io.atomic import atomic_write_text
from .io.trajectory import write_tum
from .odometry import Odometry, OdometryConfig
from .trajectory import ate_rmse, rpe


@dataclass
class OdometryRun:
    """Per frame ref: ``T_world_cam`` (4, 4, m) of the frames that were read, the seconds each step took, and
    the frames that failed (ref, error)."""

    poses: dict[FrameRef, np.ndarray] = field(default_factory=dict)
    seconds: list[float] = field(default_factory=list)
    failed: list[tuple[FrameRef, str]] = field(default_factory=list)

    @property
    def frames_per_second(self) -> float:
        """Frames per second of odometry alone (frame reading not counted)."""
        return len(self.seconds) / max(sum(self.seconds), 1e-9)


def run_odometry(rec, cfg: OdometryConfig | None = None, *,
                 on_frame: Callable[[FrameRef, str | None], None] | None = None) -> OdometryRun:
    """Odometry over every frame of ``rec`` (a ``datasets.Recording``), sequence by sequence (scene by scene).
    ``on_frame(ref, error)`` is called after each frame (error None when it was read)."""
    cfg = cfg or OdometryConfig()
    out = OdometryRun()
    odo, scene = None, None
    for ref in rec:
        if ref.scene_id != scene:
            odo, scene = Odometry(cfg), ref.scene_id
        try:
            frame = rec.frame(ref)
        except (ValueError, OSError) as e:  # InputError, missing or unreadable files: skip this frame
            odo.skip()
            out.failed.append((ref, str(e)))
            if on_frame:
                on_frame(ref, str(e))
            continue
        t0 = time.perf_counter()
        out.poses[ref] = odo.step(frame)
        out.seconds.append(time.perf_counter() - t0)
        if on_frame:
            on_frame(ref, None)
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
