"""Run the detector over every frame of a recording, writing results as it goes.

Each frame's detections JSON (``frames/<scene>_<image>.json``) is written atomically as soon as the frame is
done, and ``results.csv`` (BOP format) is always rebuilt from those files, in recording order. So a run that
was killed and then resumed (``resume=True`` skips frames whose JSON exists) writes the same ``results.csv``
as one that never stopped. A bad frame is reported and skipped, and ``failures.json`` lists it.

Frames are independent, so they can be spread over worker processes (``workers``) or a Ray cluster
(``executor="ray"``, see ``executors``); each worker builds its own ``Detector`` and the output does not
depend on where frames ran.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

from .config import PipelineConfig, dump_toml
from .datasets.base import FrameRef
from .detector import DetectionResult, Detector
from .executors import map_chunks, split
from .io.atomic import atomic_write_text
from .io.results import write_bop_csv, write_detections_json
from .model import ModelLibrary


@dataclass
class RunSummary:
    images: int = 0
    detections: int = 0
    resumed: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)


def frame_json_path(out: Path, ref: FrameRef) -> Path:
    return out / "frames" / f"{ref.scene_id:06d}_{ref.im_id:06d}.json"


def describe(ref: FrameRef) -> str:
    return f"scene {ref.scene_id} image {ref.im_id}"


def _detect_one(rec, ref: FrameRef, targets: bool, det: Detector
                ) -> tuple[FrameRef, DetectionResult | None, str | None]:
    try:
        frame = rec.frame(ref)
        tg = rec.targets(ref) if targets else None
        return ref, det.detect(frame, tg), None
    except (ValueError, OSError) as e:  # InputError, FileNotFoundError, corrupt images: skip this frame
        return ref, None, str(e)


def _detect_chunk(shared, refs: list[FrameRef]) -> list:
    """One worker's share: a detector of its own (one thread: the workers already fill the cores)."""
    rec, library, cfg, targets = shared
    det = Detector(library, cfg, workers=1)
    return [_detect_one(rec, r, targets, det) for r in refs]


def _detect_all(rec, refs: list[FrameRef], library: ModelLibrary, cfg: PipelineConfig, targets: bool,
                workers: int, executor: str, ray_address: str | None
                ) -> Iterator[tuple[FrameRef, DetectionResult | None, str | None]]:
    """Results in the order of ``refs``: here, frame by frame, or in chunks on a pool or on Ray."""
    if executor == "local" and workers <= 1:
        det = Detector(library, cfg)
        for ref in refs:
            yield _detect_one(rec, ref, targets, det)
        return
    chunks = split(refs, 4 * max(workers, 1))  # a few chunks per worker evens out slow frames
    for results in map_chunks(_detect_chunk, (rec, library, cfg, targets), chunks, workers, executor,
                              ray_address):
        yield from results


def run_recording(rec, library: ModelLibrary, cfg: PipelineConfig, out, targets: bool = False,
                  version: str = "", record_time: bool = False,
                  on_image: Callable[[FrameRef, DetectionResult | None, str | None], None] | None = None,
                  resume: bool = False, workers: int = 1, executor: str = "local",
                  ray_address: str | None = None) -> RunSummary:
    """Detect in every frame of ``rec`` (any reader of ``pcdet.datasets``).

    targets : localise the objects the recording labels per frame (BOP scene_gt.json); needs labels.
    on_image(ref, result, error) : called after each frame (result None on error; not called for frames
        skipped by ``resume``).
    resume : keep frames whose JSON already exists in ``out`` and detect only the others.
    workers : processes to spread frames over (1: this process); with Ray, the CPUs of a local instance.
    executor : "local" (processes on this machine) or "ray" (tasks on the cluster at ``ray_address``, or on a
        local Ray instance when that is None).

    The ``time`` column of results.csv is -1 (BOP's "not measured") unless ``record_time``, so that the same
    input, config and seed give a byte-identical file; per-stage times are always in the per-frame JSON."""
    out = Path(out)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    summary = RunSummary()
    todo = list(rec)
    if resume:
        todo = [r for r in todo if not _readable_json(frame_json_path(out, r))]
        summary.resumed = len(rec) - len(todo)
    pipeline = cfg.to_dict()
    for ref, result, err in _detect_all(rec, todo, library, cfg, targets, workers, executor, ray_address):
        if err is not None:
            summary.failed.append((describe(ref), err))
        else:
            summary.images += 1
            summary.detections += len(result.detections)
            summary.seconds.append(sum(result.timing_s.values()))
            info = {"scene_id": ref.scene_id, "im_id": ref.im_id, "source": rec.source(ref)}
            if ref.timestamp is not None:
                info["timestamp"] = ref.timestamp
            write_detections_json(frame_json_path(out, ref), info, result, pipeline, version)
        if on_image:
            on_image(ref, result, err)
    write_bop_csv(out / "results.csv", results_rows(out, list(rec), record_time))
    atomic_write_text(out / "config.toml", dump_toml(cfg))
    atomic_write_text(out / "failures.json", json.dumps([{"image": a, "error": b} for a, b in summary.failed],
                                                        indent=1))
    return summary


def _readable_json(path: Path) -> bool:
    try:
        json.loads(path.read_text())
        return True
    except (OSError, ValueError):
        return False


def results_rows(out: Path, refs: list[FrameRef], record_time: bool) -> list[list[str]]:
    """BOP CSV rows from the per-frame JSON files in ``out/frames`` (frames without one are left out)."""
    rows = []
    for ref in refs:
        p = frame_json_path(out, ref)
        if not p.is_file():
            continue
        doc = json.loads(p.read_text())
        t = sum(doc["timing_s"].values()) if record_time else -1.0
        for d in doc["detections"]:
            R = " ".join(f"{v:.9f}" for row in d["T_cam_model"][:3] for v in row[:3])
            tr = " ".join(f"{row[3] * 1000.0:.6f}" for row in d["T_cam_model"][:3])
            rows.append([str(ref.scene_id), str(ref.im_id), str(d["obj_id"]), f"{d['score']:.6f}", R, tr,
                         f"{t:.3f}"])
    return rows
