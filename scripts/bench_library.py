"""Library scale: the cost of a frame with 8 models against 40 (the 8 and four look-alike scaled copies of each).

The 8 models: the dataset's object (its mesh from the dataset's ``models/``, under its own id; by default the one
object its ground truth names, the LINEMOD cat of ``linemod_cat``), the six parts of ``models/`` (obj 901-906)
and the Stanford bunny (obj 907, millimetres). The 40: the same and, for each, copies scaled by 0.85, 0.92, 1.08
and 1.15 (obj 1000 n + id for the n-th scale). Frames: the dataset's real frames that show the object, no targets
(the whole library is searched). Only that object is in the library and in view, so a detection is correct when it
is the object within ADD 0.1 d (ADD-S with ``--metric adds``, for symmetric objects); every other detection
(another model, a scaled copy, the object elsewhere) is a false positive.

Prints per library: recall (frames whose object is found), precision (correct detections / all), median seconds
per frame, and the 40 / 8 time ratio; without targets, also each frame whose object is missed or that has a false
detection, with the false detections' model names and scores.

``--targets``: every model of the library is given as a target, one instance each (BOP localisation, as on an
LM-O frame with its 8 objects named): the cost of searching that many given objects in one real frame. Only the
object is in view, so precision is not meaningful there (each target keeps its best pose). ``--depth-only``: the
colour images are dropped (LM-O's test frames are used without colour).

``--save DIR``: only write the two libraries as BOP model folders ``DIR/lib8`` and ``DIR/lib40`` (for ``pcdet
synth --models DIR/lib8``: synthetic scenes of the same 8 objects).

Run:  python scripts/bench_library.py [--data ../shared/data/linemod_cat] [--object ID] [--frames 20]
                                      [--pipeline default] [--metric add] [--targets] [--depth-only]
                                      [--only 8] [--save DIR]
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
from pcdet.metrics import add, adds

ROOT = Path(__file__).resolve().parent.parent
SCALES = (0.85, 0.92, 1.08, 1.15)


def _write(mesh: trimesh.Trimesh, folder: Path, obj_id: int, name: str, info: dict) -> None:
    mesh.export(folder / f"obj_{obj_id:06d}.ply")
    info[str(obj_id)] = {"name": name, "diameter": float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))}


PART_IDS = 901  # the six parts take obj 901-906, the bunny 907: clear of BOP's object ids (1-30)
SHARED = ROOT.parent / "shared" / "data"


def build_libraries(data: Path, out: Path, obj_id: int) -> tuple[Path, Path]:
    """Two BOP model folders under ``out``: ``lib8`` and ``lib40`` (see the module docstring), with ``data``'s
    object ``obj_id``."""
    mesh_path = data / "models" / f"obj_{obj_id:06d}.ply"
    if not mesh_path.is_file():
        raise SystemExit(f"error: {mesh_path}: no mesh of object {obj_id} in the dataset's models folder")
    if not 0 < obj_id < PART_IDS:
        raise SystemExit(f"error: --object {obj_id}: ids 1-{PART_IDS - 1} only (the parts take {PART_IDS} on)")
    info_path = data / "models" / "models_info.json"
    own = json.loads(info_path.read_text()).get(str(obj_id), {}) if info_path.is_file() else {}
    base: list[tuple[int, str, trimesh.Trimesh]] = [
        (obj_id, own.get("name", f"obj{obj_id}"), trimesh.load(mesh_path, process=False))]
    info = json.loads((ROOT / "models" / "models_info.json").read_text())
    for i in range(1, 7):
        name = info[str(i)].get("name", f"part{i}")
        base.append((PART_IDS - 1 + i, name, trimesh.load(ROOT / "models" / f"obj_{i:06d}.ply", process=False)))
    bunny_path = next((d / "bunny" / "bun_zipper_res3.ply" for d in (data.parent, SHARED)
                       if (d / "bunny" / "bun_zipper_res3.ply").is_file()), None)
    if bunny_path is None:
        raise SystemExit(f"error: {SHARED / 'bunny' / 'bun_zipper_res3.ply'}: the bunny's mesh is missing")
    bunny = trimesh.load(bunny_path, process=False)
    bunny.apply_scale(1000.0)  # metres -> millimetres, as BOP model folders are read
    base.append((PART_IDS + 6, "bunny", bunny))
    libs = []
    for name, scales in (("lib8", ()), ("lib40", SCALES)):
        folder = out / name
        folder.mkdir(parents=True)
        meta: dict = {}
        for oid, label, mesh in base:
            _write(mesh, folder, oid, label, meta)
            for n, s in enumerate(scales, start=1):
                copy = mesh.copy()
                copy.apply_scale(s)
                _write(copy, folder, 1000 * n + oid, f"{label}x{s:.2f}", meta)
        (folder / "models_info.json").write_text(json.dumps(meta, indent=1))
        libs.append(folder)
    return libs[0], libs[1]


def shown_object(data: Path, rec, refs, obj_id: int | None) -> int:
    """``obj_id``, or the one object the frames' ground truth names (an error when it names several or none)."""
    if obj_id is not None:
        return obj_id
    ids = sorted({g["obj_id"] for ref in refs for g in rec.gt(ref)})
    if len(ids) != 1:
        raise SystemExit(f"error: {data}: the ground truth names objects {ids}; choose one with --object")
    return ids[0]


def run(folder: Path, rec, refs, obj_id: int, pipeline: str, targets: bool = False, depth_only: bool = False,
        metric=add) -> dict:
    cfg = load_pipeline(pipeline)
    t0 = time.perf_counter()
    lib = ModelLibrary.from_folder(folder, cfg)
    build = time.perf_counter() - t0
    det = Detector(lib, cfg)
    obj = lib[lib.index_of(obj_id)]
    times, found, correct, total = [], 0, 0, 0
    for ref in refs:
        frame = rec.frame(ref)
        if depth_only:
            frame = dataclasses.replace(frame, rgb=None)
        T_gt = next(g["T_cam_model"] for g in rec.gt(ref) if g["obj_id"] == obj_id)
        t = time.perf_counter()
        res = det.detect(frame, {m.obj_id: 1 for m in lib} if targets else None)
        times.append(time.perf_counter() - t)
        ok = [d.obj_id == obj_id and metric(d.T_cam_model, T_gt, obj.points) < 0.1 * obj.diameter
              for d in res.detections]
        found += any(ok)
        correct += sum(ok)
        total += len(res.detections)
        wrong = [f"{d.model} {d.score:.3f}" for d, good in zip(res.detections, ok) if not good]
        if not targets and (wrong or not any(ok)):  # with targets every model keeps a pose: not listed
            print(f"  frame {ref.im_id}: {'' if any(ok) else f'{obj.name} missed; '}false: "
                  f"{', '.join(wrong) or 'none'}", flush=True)
    return {"models": len(lib), "recall": found / len(refs), "precision": correct / max(total, 1),
            "detections": total, "median_s": float(np.median(times)), "build_s": build}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=SHARED / "linemod_cat")
    ap.add_argument("--object", type=int, default=None,
                    help="the dataset's object id (default: the one object its ground truth names)")
    ap.add_argument("--frames", type=int, default=20, help="first N frames that show the object (0: all)")
    ap.add_argument("--pipeline", default="default")
    ap.add_argument("--metric", choices=("add", "adds"), default="add",
                    help="a detection is correct within 0.1 d of this (adds: for symmetric objects)")
    ap.add_argument("--targets", action="store_true", help="give every library model as a target (one each)")
    ap.add_argument("--depth-only", action="store_true", help="drop the colour images")
    ap.add_argument("--only", type=int, choices=(8, 40), default=None, help="run one library only")
    ap.add_argument("--save", type=Path, default=None, help="only write DIR/lib8 and DIR/lib40, then stop")
    args = ap.parse_args()
    try:
        rec = open_recording(args.data)
    except (OSError, ValueError) as e:  # InputError is a ValueError
        raise SystemExit(f"error: {e}") from None
    obj_id = shown_object(args.data, rec, list(rec), args.object)
    if args.save is not None:
        if args.save.exists() and any(args.save.iterdir()):
            ap.error(f"--save {args.save}: the folder is not empty")
        args.save.mkdir(parents=True, exist_ok=True)
        for lib in build_libraries(args.data, args.save, obj_id):
            print(f"written: {lib}")
        return
    refs = [ref for ref in rec if any(g["obj_id"] == obj_id for g in rec.gt(ref))]
    if not refs:
        raise SystemExit(f"error: {args.data}: no frame shows object {obj_id}")
    refs = refs[: args.frames] if args.frames > 0 else refs
    tmp = Path(tempfile.mkdtemp(prefix="pcdet-lib-"))
    try:
        lib8, lib40 = build_libraries(args.data, tmp, obj_id)
        rows = []
        for folder in [f for f, n in ((lib8, 8), (lib40, 40)) if args.only in (None, n)]:
            rows.append(run(folder, rec, refs, obj_id, args.pipeline, args.targets, args.depth_only,
                            {"add": add, "adds": adds}[args.metric]))
            print(f"{rows[-1]['models']} models: recall {rows[-1]['recall']:.3f}, precision "
                  f"{rows[-1]['precision']:.3f}, median {rows[-1]['median_s']:.2f} s/frame", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    given = "every model given as a target" if args.targets else "no targets"
    colour = ", depth only" if args.depth_only else ""
    print(f"\n{len(refs)} real frames of {args.data.name} (object {obj_id}), {given}{colour}, "
          f"pipeline {args.pipeline}\n")
    print("| models | recall | precision | detections | median s/frame | time / 8 models | model build s |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['models']} | {r['recall']:.3f} | {r['precision']:.3f} | {r['detections']} | "
              f"{r['median_s']:.2f} | {r['median_s'] / rows[0]['median_s']:.2f}x | {r['build_s']:.0f} |")


if __name__ == "__main__":
    main()
