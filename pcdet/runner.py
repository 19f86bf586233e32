"""Run the detector over every image of a BOP dataset, writing results as it goes.

Each image's detections JSON is written atomically as soon as it is done; ``results.csv`` (BOP format) and
``config.toml`` (the resolved pipeline) are written at the end. A bad image is reported and skipped.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from .config import PipelineConfig, dump_toml
from .datasets.bop import BopDataset, BopImage
from .detector import DetectionResult, Detector
from .io.atomic import atomic_write_text
from .io.results import bop_rows, write_bop_csv, write_detections_json
from .model import ModelLibrary


@dataclass
class RunSummary:
    images: int = 0
    detections: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)


def run_dataset(ds: BopDataset, library: ModelLibrary, cfg: PipelineConfig, out, targets: bool = False,
                version: str = "", record_time: bool = False,
                on_image: Callable[[BopImage, DetectionResult | None, str | None], None] | None = None
                ) -> RunSummary:
    """Detect in every image of ``ds``; ``targets`` uses scene_gt.json's object ids and counts (BOP
    localisation). ``on_image(img, result, error)`` is called after each image (result None on error).

    The ``time`` column of results.csv is -1 (BOP's "not measured") unless ``record_time``, so that the same
    input, config and seed give a byte-identical file; per-stage times are always in the per-image JSON."""
    out = Path(out)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    det = Detector(library, cfg)
    rows: list[list[str]] = []
    summary = RunSummary()
    pipeline = cfg.to_dict()
    for img in ds:
        try:
            frame = ds.frame(img)
            tg = ds.targets(img) if targets else None
            result = det.detect(frame, tg)
        except (ValueError, OSError) as e:  # InputError, FileNotFoundError, corrupt images: skip this one
            summary.failed.append((f"scene {img.scene_id} image {img.im_id}", str(e)))
            if on_image:
                on_image(img, None, str(e))
            continue
        t = sum(result.timing_s.values())
        summary.images += 1
        summary.detections += len(result.detections)
        summary.seconds.append(t)
        rows += bop_rows(img.scene_id, img.im_id, result.detections, t if record_time else -1.0)
        info = {"scene_id": img.scene_id, "im_id": img.im_id, "source": str(ds.depth_path(img))}
        write_detections_json(out / "frames" / f"{img.scene_id:06d}_{img.im_id:06d}.json", info, result,
                              pipeline, version)
        if on_image:
            on_image(img, result, None)
    write_bop_csv(out / "results.csv", rows)
    atomic_write_text(out / "config.toml", dump_toml(cfg))
    atomic_write_text(out / "failures.json", json.dumps([{"image": a, "error": b} for a, b in summary.failed],
                                                        indent=1))
    return summary
