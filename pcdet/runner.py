"""Run the detector over every frame of a recording, writing results as it goes.

Each frame's detections JSON (``frames/<scene>_<image>.json``) is written atomically as soon as the frame is
done, and ``results.csv`` (BOP format) is always rebuilt from those files, in recording order. So a run that
was killed and then resumed (``resume=True`` skips frames whose JSON exists) writes the same ``results.csv``
as one that never stopped. A bad frame is reported and skipped, and ``failures.json`` lists it.

The output folder is a ``RunFolder``: locked while a run writes into it, and described by ``run.json``
(recording, format, targets, mode, pipeline), so that a resumed run cannot mix frames made from another
recording or with another pipeline, and a new run does not silently sit beside an old one's frames.

Frames are independent, so they can be spread over worker processes (``workers``) or a Ray cluster
(``executor="ray"``, see ``executors``); each worker builds its own ``Detector`` once, every frame is written
as soon as it comes back, and the output does not depend on where frames ran.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

from .config import PipelineConfig, dump_toml
from .datasets.base import FrameRef
from .detector import DetectionResult, Detector
from .errors import InputError, internal_error
from .executors import map_unordered
from .io.atomic import atomic_write_text
from .io.bop import results_row, write_results_csv
from .io.jsonfile import read_json
from .io.outputs import FolderLock, check_folder
from .io.results import write_detections_json
from .library import ModelLibrary


@dataclass
class RunSummary:
    """What a run did: frames detected, detections, frames kept from before, failures (frame, error), seconds per
    frame."""

    images: int = 0
    detections: int = 0
    resumed: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)


@dataclass(frozen=True)
class RunOptions:
    """How ``run_recording`` runs.

    targets : localise the objects the recording labels per frame (``rec.targets``: BOP scene_gt.json, or a BOP
        target list the dataset was restricted to); needs labels.
    resume : keep frames whose JSON already exists in the output folder and detect only the others.
    workers : processes to spread frames over (1: this process); with Ray, the CPUs of a local instance.
    threads : the detector's threads in this process when ``workers`` is 1 (None: the machine's cores); worker
        processes use one each. The output does not depend on it.
    executor : "local" (processes on this machine) or "ray" (tasks on the cluster at ``ray_address``, or on a
        local Ray instance when that is None).
    record_time : write measured seconds into results.csv's ``time`` column (else -1, BOP's "not measured",
        so that the same input, config and seed give a byte-identical file).
    version : pcdet's version, written into each frame's JSON.
    """

    targets: bool = False
    resume: bool = False
    workers: int = 1
    threads: int | None = None
    executor: str = "local"
    ray_address: str | None = None
    record_time: bool = False
    version: str = ""
    overwrite: bool = False


RUN_FILES = ("results.csv", "config.toml", "failures.json", "run.json", "tracks.json")


class RunFolder:
    """The output folder of one run, checked and locked before any work starts (``close()`` releases it).

    A folder that already holds a run (frames or ``run.json``) is refused unless ``resume`` (continue it; its
    ``run.json`` must name the same recording, format, targets, mode and pipeline) or ``overwrite`` (its
    frames and pcdet's files in it are removed first). ``targets``: False, True (scene_gt.json) or a string
    naming the target list. Raises ``InputError`` naming the folder."""

    def __init__(self, out, rec, cfg: PipelineConfig, *, resume: bool = False, overwrite: bool = False,
                 targets: bool | str = False, mode: str = "detect", version: str = ""):
        self.path = check_folder(out, "output folder")
        self.frames = self.path / "frames"
        self._lock = FolderLock(self.path).acquire()
        try:
            self.manifest = {"recording": str(Path(rec.root).resolve()), "format": rec.format, "frames": len(rec),
                             "targets": targets, "mode": mode, "pipeline": cfg.to_dict()}
            self._reconcile(resume, overwrite)
            atomic_write_text(self.path / "run.json", json.dumps({"pcdet_version": version, **self.manifest},
                                                                 indent=1))
            self.frames.mkdir(exist_ok=True)
        except BaseException:
            self.close()
            raise

    def _reconcile(self, resume: bool, overwrite: bool) -> None:
        written = sorted(self.frames.glob("*.json")) if self.frames.is_dir() else []
        old_path = self.path / "run.json"
        if overwrite:
            # the checkpoints, and an earlier pcdet's pickled ones
            states = sorted(p for p in (self.path / "tracking_state").glob("*") if p.suffix in (".npz", ".pkl"))
            for p in written + states + [self.path / f for f in RUN_FILES]:
                p.unlink(missing_ok=True)
            return
        if not written and not old_path.exists():
            return
        if not resume:
            raise InputError(f"already holds a run ({len(written)} frame(s) written): continue it with --resume, "
                             "or start over with --overwrite", self.path)
        try:
            old = read_json(old_path)
        except (OSError, ValueError):
            raise InputError("holds frames but no readable run.json (written by an older pcdet?), so how they "
                             "were made is unknown: start over with --overwrite", self.path) from None
        diffs = _differences({k: old.get(k) for k in self.manifest if k != "frames"},
                             {k: v for k, v in self.manifest.items() if k != "frames"})
        if diffs:
            raise InputError("--resume: its frames were made differently (" + "; ".join(diffs[:4])
                             + (f"; {len(diffs) - 4} more" if len(diffs) > 4 else "")
                             + "): use another folder, or start over with --overwrite", self.path)

    def frame_path(self, ref: FrameRef) -> Path:
        """The detections JSON of a frame in this folder."""
        return frame_json_path(self.path, ref)

    def close(self) -> None:
        """Release the folder's lock."""
        self._lock.release()


def _differences(old, new, prefix: str = "") -> list[str]:
    """'field: old -> new' for every leaf that differs between two nested dicts."""
    out = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k), new.get(k)
        if isinstance(a, dict) and isinstance(b, dict):
            out += _differences(a, b, f"{prefix}{k}.")
        elif a != b:
            out.append(f"{prefix}{k}: {a!r} then, {b!r} now")
    return out


def frame_json_path(out: Path, ref: FrameRef) -> Path:
    """``out/frames/<scene>_<image>.json``, six digits each."""
    return out / "frames" / f"{ref.scene_id:06d}_{ref.im_id:06d}.json"


def describe(ref: FrameRef) -> str:
    """A frame named for people: ``scene S image I``."""
    return f"scene {ref.scene_id} image {ref.im_id}"


def _detect_one(rec, ref: FrameRef, targets: bool, det: Detector
                ) -> tuple[FrameRef, DetectionResult | None, str | None]:
    try:
        frame = rec.frame(ref)
        tg = rec.targets(ref) if targets else None
        return ref, det.detect(frame, tg), None
    except (ValueError, OSError) as e:  # InputError, FileNotFoundError, corrupt images: skip this frame
        return ref, None, str(e)
    except Exception as e:  # a bug met on this frame: reported with where it was raised, and the batch goes on
        return ref, None, internal_error(e)


def _worker_setup(shared):
    """A worker's state: the recording, a detector of its own (one thread: the workers fill the cores)."""
    rec, library, cfg, targets = shared
    return rec, Detector(library, cfg, workers=1), targets


def _worker_task(state, ref: FrameRef):
    rec, det, targets = state
    return _detect_one(rec, ref, targets, det)


def _detect_all(rec, refs: list[FrameRef], library: ModelLibrary, cfg: PipelineConfig, opt: RunOptions
                ) -> Iterator[tuple[FrameRef, DetectionResult | None, str | None]]:
    """Results here in the order of ``refs``, or from worker processes or Ray as each frame is done."""
    if opt.executor == "local" and opt.workers <= 1:
        det = Detector(library, cfg, workers=opt.threads)
        for ref in refs:
            yield _detect_one(rec, ref, opt.targets, det)
        return
    yield from map_unordered(_worker_setup, _worker_task, (rec, library, cfg, opt.targets), refs,
                             workers=opt.workers, executor=opt.executor, ray_address=opt.ray_address)


def run_recording(rec, library: ModelLibrary, cfg: PipelineConfig, out: "Path | str | RunFolder",
                  options: RunOptions | None = None, *,
                  on_image: Callable[[FrameRef, DetectionResult | None, str | None], None] | None = None
                  ) -> RunSummary:
    """Detect in every frame of ``rec`` (any reader of ``pcdet.datasets``), writing into the folder ``out`` (a
    path, or a ``RunFolder`` opened beforehand): ``frames/<scene>_<image>.json`` as each frame is done, then
    ``results.csv`` (BOP), ``config.toml`` (the resolved pipeline) and ``failures.json``; ``run.json`` says how
    the frames were made. ``options``: see ``RunOptions``.

    on_image(ref, result, error) : called after each frame (result None on error; not called for frames
        skipped by ``resume``)."""
    opt = options or RunOptions()
    folder = out if isinstance(out, RunFolder) else RunFolder(out, rec, cfg, resume=opt.resume, overwrite=opt.overwrite,
                                                             targets=opt.targets, version=opt.version)
    try:
        return _run(rec, library, cfg, folder.path, opt, on_image)
    finally:
        if folder is not out:
            folder.close()


def _run(rec, library, cfg, out: Path, opt: RunOptions, on_image) -> RunSummary:
    summary = RunSummary()
    todo = list(rec)
    if opt.resume:
        todo = [r for r in todo if not _readable_json(frame_json_path(out, r))]
        summary.resumed = len(rec) - len(todo)
    pipeline = cfg.to_dict()
    for ref, result, err in _detect_all(rec, todo, library, cfg, opt):
        if err is not None:
            summary.failed.append((describe(ref), err))
        else:
            summary.images += 1
            summary.detections += len(result.detections)
            summary.seconds.append(sum(result.timing_s.values()))
            info = {"scene_id": ref.scene_id, "im_id": ref.im_id, "source": rec.source(ref)}
            if ref.timestamp is not None:
                info["timestamp"] = ref.timestamp
            write_detections_json(frame_json_path(out, ref), info, result, pipeline, opt.version)
        if on_image:
            on_image(ref, result, err)
    write_results_csv(out / "results.csv", results_rows(out, list(rec), opt.record_time))
    atomic_write_text(out / "config.toml", dump_toml(cfg))
    atomic_write_text(out / "failures.json", json.dumps([{"image": a, "error": b} for a, b in summary.failed],
                                                        indent=1))
    return summary


def _readable_json(path: Path) -> bool:
    try:
        read_json(path)
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
        doc = read_json(p)
        t = sum(doc["timing_s"].values()) if record_time else -1.0
        rows += [results_row(ref.scene_id, ref.im_id, d["obj_id"], d["score"], d["T_cam_model"], t)
                 for d in doc["detections"]]
    return rows
