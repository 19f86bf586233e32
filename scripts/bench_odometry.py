"""Camera odometry against ground truth: KISS-ICP, frame-to-frame ICP and the default (KISS-ICP refined frame to
frame), beside the trivial baselines (the camera never moves; the first true motion repeated), on
../shared/data/open3d_rgbd and on a synthetic table-top recording.

Prints ATE (RMS position error after rigid alignment, mm), RPE over one frame (RMS, mm and deg) and frames/s.
Run:  python scripts/bench_odometry.py [--frames 60] [--seed 2026] [--data REC ...]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from pcdet.datasets import open_recording
from pcdet.library import ModelLibrary
from pcdet.odometry import OdometryConfig, odometry
from pcdet.synth import SynthConfig, synthesize
from pcdet.trajectory import (
    ate_rmse,
    constant_velocity_baseline,
    identity_baseline,
    rpe,
)

ROOT = Path(__file__).resolve().parent.parent


def table(rec, label):
    refs = list(rec)
    gtd = rec.camera_poses()
    gt = [np.linalg.inv(gtd[refs[0]]) @ gtd[r] for r in refs]
    frames = [rec.frame(r) for r in refs]
    print(f"\n{label}: {len(refs)} frames")
    print("| method | ATE (mm) | RPE (mm) | RPE (deg) | frames/s |")
    print("|---|---|---|---|---|")

    def row(name, est, fps=None):
        tr, rr = rpe(est, gt)
        print(f"| {name} | {ate_rmse(est, gt) * 1000:.1f} | {tr * 1000:.1f} | {rr:.2f} | "
              f"{'' if fps is None else f'{fps:.1f}'} |", flush=True)

    row("identity (no motion)", identity_baseline(gt))
    row("constant velocity (first true step)", constant_velocity_baseline(gt))
    for m in ("kiss", "icp", "kiss+icp"):
        t0 = time.perf_counter()
        est = list(odometry(frames, OdometryConfig(method=m)))
        row({"kiss": "KISS-ICP", "icp": "frame-to-frame ICP", "kiss+icp": "KISS-ICP + ICP (default)"}[m], est,
            len(frames) / (time.perf_counter() - t0))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--data", type=Path, nargs="*", default=None)
    args = ap.parse_args()
    if args.data:
        for d in args.data:
            table(open_recording(d), str(d))
        return
    o3d_rgbd = ROOT.parent / "shared" / "data" / "open3d_rgbd"
    if o3d_rgbd.is_dir():
        table(open_recording(o3d_rgbd), "open3d_rgbd (ICL-NUIM living room, rendered)")
    with tempfile.TemporaryDirectory() as tmp:
        lib = ModelLibrary.from_folder(ROOT / "models")
        rec = synthesize(lib, Path(tmp) / "seq", SynthConfig(scenes=1, objects=4, sequence=args.frames,
                                                             seed=args.seed))
        table(open_recording(rec), f"synthetic table-top recording (pcdet synth --sequence {args.frames} "
                                   f"--seed {args.seed})")


if __name__ == "__main__":
    main()
