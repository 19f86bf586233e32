"""Library scale: the cost of a frame with 8 models against 40 (the 8 and four look-alike scaled copies of each).

The 8 models: the LINEMOD cat (its textured mesh, obj 6), the six parts of ``models/`` (obj 11-16) and the
Stanford bunny (obj 17, millimetres). The 40: the same and, for each, copies scaled by 0.85, 0.92, 1.08 and 1.15
(obj 100 + id, 200 + id, ...). Frames: real LINEMOD cat frames, no targets (the whole library is searched).
Only the cat is in the library and in view, so a detection is correct when it is the cat within ADD 0.1 d;
every other detection (another model, a scaled cat, a cat elsewhere) is a false positive.

Prints per library: recall (frames whose cat is found), precision (correct detections / all), median seconds
per frame, and the 40 / 8 time ratio; without targets, also each frame whose cat is missed or that has a false
detection, with the false detections' model names and scores.

``--targets``: every model of the library is given as a target, one instance each (BOP localisation, as on an
LM-O frame with its 8 objects named): the cost of searching that many given objects in one real frame. Only the
cat is in view, so precision is not meaningful there (each target keeps its best pose). ``--depth-only``: the
colour images are dropped (LM-O's test frames are used without colour).

``--save DIR``: only write the two libraries as BOP model folders ``DIR/lib8`` and ``DIR/lib40`` (for ``pcdet
synth --models DIR/lib8``: synthetic scenes of the same 8 objects).

Run:  python scripts/bench_library.py [--data ../shared/data/linemod_cat] [--frames 20] [--pipeline default]
                                      [--targets] [--depth-only] [--only 8] [--save DIR]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from pcdet.config import load_pipeline
from pcdet.datasets import open_recording
from pcdet.detector import Detector
from pcdet.library import ModelLibrary
from pcdet.metrics import add

ROOT = Path(__file__).resolve().parent.parent
SCALES = (0.85, 0.92, 1.08, 1.15)


def _write(mesh: trimesh.Trimesh, folder: Path, obj_id: int, name: str, info: dict) -> None:
    mesh.export(folder / f"obj_{obj_id:06d}.ply")
    info[str(obj_id)] = {"name": name, "diameter": float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))}


def build_libraries(data: Path, out: Path) -> tuple[Path, Path]:
    """Two BOP model folders under ``out``: ``lib8`` and ``lib40`` (see the module docstring)."""
    base: list[tuple[int, str, trimesh.Trimesh]] = []
    base.append((6, "cat", trimesh.load(data / "models" / "obj_000006.ply", process=False)))
    info = json.loads((ROOT / "models" / "models_info.json").read_text())
    for i in range(1, 7):
        name = info[str(i)].get("name", f"part{i}")
        base.append((10 + i, name, trimesh.load(ROOT / "models" / f"obj_{i:06d}.ply", process=False)))
    bunny = trimesh.load(data.parent / "bunny" / "bun_zipper_res3.ply", process=False)
    bunny.apply_scale(1000.0)  # metres -> millimetres, as BOP model folders are read
    base.append((17, "bunny", bunny))
    libs = []
    for name, scales in (("lib8", ()), ("lib40", SCALES)):
        folder = out / name
        folder.mkdir(parents=True)
        meta: dict = {}
        for obj_id, label, mesh in base:
            _write(mesh, folder, obj_id, label, meta)
            for n, s in enumerate(scales, start=1):
                copy = mesh.copy()
                copy.apply_scale(s)
                _write(copy, folder, 100 * n + obj_id, f"{label}x{s:.2f}", meta)
        (folder / "models_info.json").write_text(json.dumps(meta, indent=1))
        libs.append(folder)
    return libs[0], libs[1]


def run(folder: Path, rec, refs, pipeline: str, targets: bool = False, depth_only: bool = False) -> dict:
    cfg = load_pipeline(pipeline)
    t0 = time.perf_counter()
    lib = ModelLibrary.from_folder(folder, cfg)
    build = time.perf_counter() - t0
    det = Detector(lib, cfg)
    cat = lib[lib.index_of(6)]
    times, found, correct, total = [], 0, 0, 0
    for ref in refs:
        frame = rec.frame(ref)
        if depth_only:
            frame = dataclasses.replace(frame, rgb=None)
        T_gt = next(g["T_cam_model"] for g in rec.gt(ref) if g["obj_id"] == 6)
        t = time.perf_counter()
        res = det.detect(frame, {m.obj_id: 1 for m in lib} if targets else None)
        times.append(time.perf_counter() - t)
        ok = [d.obj_id == 6 and add(d.T_cam_model, T_gt, cat.points) < 0.1 * cat.diameter for d in res.detections]
        found += any(ok)
        correct += sum(ok)
        total += len(res.detections)
        wrong = [f"{d.model} {d.score:.3f}" for d, good in zip(res.detections, ok) if not good]
        if not targets and (wrong or not any(ok)):  # with targets every model keeps a pose: not listed
            print(f"  frame {ref.im_id}: {'' if any(ok) else 'cat missed; '}false: {', '.join(wrong) or 'none'}",
                  flush=True)
    return {"models": len(lib), "recall": found / len(refs), "precision": correct / max(total, 1),
            "detections": total, "median_s": float(np.median(times)), "build_s": build}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "linemod_cat")
    ap.add_argument("--frames", type=int, default=20, help="first N frames (0: all)")
    ap.add_argument("--pipeline", default="default")
    ap.add_argument("--targets", action="store_true", help="give every library model as a target (one each)")
    ap.add_argument("--depth-only", action="store_true", help="drop the colour images")
    ap.add_argument("--only", type=int, choices=(8, 40), default=None, help="run one library only")
    ap.add_argument("--save", type=Path, default=None, help="only write DIR/lib8 and DIR/lib40, then stop")
    args = ap.parse_args()
    if args.save is not None:
        if args.save.exists() and any(args.save.iterdir()):
            ap.error(f"--save {args.save}: the folder is not empty")
        args.save.mkdir(parents=True, exist_ok=True)
        for lib in build_libraries(args.data, args.save):
            print(f"written: {lib}")
        return
    rec = open_recording(args.data)
    refs = list(rec)
    refs = refs[: args.frames] if args.frames > 0 else refs
    tmp = Path(tempfile.mkdtemp(prefix="pcdet-lib-"))
    try:
        lib8, lib40 = build_libraries(args.data, tmp)
        rows = []
        for folder in [f for f, n in ((lib8, 8), (lib40, 40)) if args.only in (None, n)]:
            rows.append(run(folder, rec, refs, args.pipeline, args.targets, args.depth_only))
            print(f"{rows[-1]['models']} models: recall {rows[-1]['recall']:.3f}, precision "
                  f"{rows[-1]['precision']:.3f}, median {rows[-1]['median_s']:.2f} s/frame", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    given = "every model given as a target" if args.targets else "no targets"
    colour = ", depth only" if args.depth_only else ""
    print(f"\n{len(refs)} real frames of {args.data.name}, {given}{colour}, pipeline {args.pipeline}\n")
    print("| models | recall | precision | detections | median s/frame | time / 8 models | model build s |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['models']} | {r['recall']:.3f} | {r['precision']:.3f} | {r['detections']} | "
              f"{r['median_s']:.2f} | {r['median_s'] / rows[0]['median_s']:.2f}x | {r['build_s']:.0f} |")


if __name__ == "__main__":
    main()
