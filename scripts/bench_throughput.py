"""Throughput of `pcdet run` in detection mode on this machine: one process, a local process pool, and Ray.

Runs the same synthetic suite (BOP layout, 640x480, 6-model library, no targets) with each executor, checks that
every results.csv is byte-identical to the one-process run, and prints frames/s (wall clock, including pool
or Ray start-up) with the ratio to one process.
Run:  python scripts/bench_throughput.py [--scenes 20] [--seed 2026] [--data BOP_DIR] [--no-ray]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from pcdet.config import PipelineConfig
from pcdet.datasets import open_recording
from pcdet.library import ModelLibrary
from pcdet.runner import RunOptions, run_recording
from pcdet.synth import SynthConfig, synthesize

ROOT = Path(__file__).resolve().parent.parent


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--data", type=Path, default=None)
    ap.add_argument("--no-ray", action="store_true")
    args = ap.parse_args()
    lib = ModelLibrary.from_folder(ROOT / "models")
    with tempfile.TemporaryDirectory() as tmp:
        # the idealised scenes (edge pixels dropped, exact meshes), where docs/measurements.md's figures come from
        data = args.data or synthesize(lib, Path(tmp) / "suite", SynthConfig(scenes=args.scenes, objects=4,
                                                                             seed=args.seed, sensor="structured_light",
                                                                             mesh_error=0))
        rec = open_recording(data)
        runs = [("1 process", 1, "local"), ("2 processes", 2, "local")]
        if not args.no_ray:
            runs.append(("Ray, local instance, 2 CPUs", 2, "ray"))
        rows, ref = [], None
        for name, w, ex in runs:
            out = Path(tmp) / name.replace(" ", "_").replace(",", "")
            t0 = time.perf_counter()
            run_recording(rec, lib, PipelineConfig(), out, RunOptions(workers=w, executor=ex))
            dt = time.perf_counter() - t0
            csv = (out / "results.csv").read_bytes()
            ref = ref or csv
            rows.append((name, len(rec) / dt, csv == ref))
            print(f"{name}: {len(rec) / dt:.2f} frames/s", flush=True)
    print(f"\n{len(rec)} frames, 640x480, {len(lib)}-model library, no targets")
    print("| executor | frames/s | vs 1 process | results.csv identical |")
    print("|---|---|---|---|")
    for name, fps, same in rows:
        print(f"| {name} | {fps:.2f} | {fps / rows[0][1]:.2f}x | {'yes' if same else 'NO'} |")


if __name__ == "__main__":
    main()
