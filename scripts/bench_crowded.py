"""Many instances in clutter: the three groupers side by side on crowded synthetic scenes, without targets.

Scenes: ``--objects`` library objects, each with 1..``--instances`` copies, plus ``--distractors`` clutter shapes
that are not in the library, on a table (``pcdet synth --instances 3 --distractors 3``). Every method searches
all six models and is told nothing. Scores: recall at ADD-S < 0.1 d, precision (share of detections that
match a ground-truth instance at ADD-S < 0.1 d), median seconds per frame.

Each pipeline is run with each ``--selection``: ``global`` (hypothesis verification over the whole scene) and
``threshold`` (every detection above the score threshold, greedy conflicts), which shows what global
verification gains.

Run:  python scripts/bench_crowded.py [--scenes 20] [--seed 2026] [--selection global,threshold]
          [--pipelines crowded+ransac,crowded+gc,crowded+hough] [--data EXISTING_BOP_DIR]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from pcdet.config import load_pipeline
from pcdet.datasets.bop import BopDataset
from pcdet.detector import Detector
from pcdet.evaluate import evaluate
from pcdet.library import ModelLibrary
from pcdet.synth import SynthConfig, synthesize

ROOT = Path(__file__).resolve().parent.parent


def detect_all(det: Detector, frames: list) -> tuple[list[dict], list[float]]:
    """Run ``det`` on every ``(image, frame)`` of ``frames``, told nothing: the estimates as ``evaluate``
    takes them, and the seconds each frame took."""
    ests, times = [], []
    for img, frame in frames:
        t0 = time.perf_counter()
        res = det.detect(frame)
        times.append(time.perf_counter() - t0)
        ests += [{"scene_id": img.scene_id, "im_id": img.im_id, "obj_id": d.obj_id, "score": d.score,
                  "T_cam_model": d.T_cam_model} for d in res.detections]
    return ests, times


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--objects", type=int, default=3)
    ap.add_argument("--instances", type=int, default=3)
    ap.add_argument("--distractors", type=int, default=3)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--data", type=Path, default=None, help="existing BOP dataset (default: synthesise one)")
    ap.add_argument("--pipelines", default="crowded+ransac,crowded+gc,crowded+hough",
                    help="comma-separated presets (names, a+b layered, or TOML paths)")
    ap.add_argument("--selection", default="global,threshold", help="verify.selection values to run")
    args = ap.parse_args()
    lib = ModelLibrary.from_folder(ROOT / "models")
    tmp = None
    if args.data is None:
        tmp = tempfile.TemporaryDirectory()
        args.data = synthesize(lib, Path(tmp.name) / "crowded",
                               SynthConfig(scenes=args.scenes, objects=args.objects, instances=args.instances,
                                           distractors=args.distractors, seed=args.seed))
    ds = BopDataset(args.data)
    frames = [(img, ds.frame(img)) for img in ds]
    rows = []
    for pipe in args.pipelines.split(","):
        for sel in args.selection.split(","):
            cfg = load_pipeline(pipe).replace(verify={"selection": sel})
            ests, times = detect_all(Detector(lib, cfg), frames)
            ov = evaluate(ds, ests, lib, with_vsd=False).overall
            rows.append((pipe, sel, ov["recall_adds"], ov["precision_adds"], ov["estimates"],
                         float(np.median(times))))
            print(f"{pipe:16s} {sel:9s} recall ADD-S {ov['recall_adds']:.3f}  precision "
                  f"{ov['precision_adds']:.3f}  ({ov['estimates']} detections)  median {np.median(times):.3f} "
                  "s/frame", flush=True)
    n_inst = sum(len(ds.gt(img)) for img, _ in frames)
    print(f"\n{len(frames)} frames, {n_inst} instances, {args.distractors} distractors per scene requested, "
          f"{len(lib)}-model library, seed {args.seed}, no targets")
    print("| pipeline | selection | recall ADD-S | precision | detections | median s/frame |")
    print("|---|---|---|---|---|---|")
    for p, g, r, pr, n, t in rows:
        print(f"| {p} | {g} | {r:.3f} | {pr:.3f} | {n} | {t:.3f} |")


if __name__ == "__main__":
    main()
