"""Tracking on a synthetic recording with exact ground truth: per-object world-frame error over all frames, and
the speed of tracking frames (ICP from the predicted pose) against full-detection frames.

Two errors per object: of the world poses observed frame by frame (the corrected camera pose x the object's pose
found in the frame; the positions of the model's origin), and of the poses tracking reports (``results.csv``: the
mean of the views since the map pose was set, seen from the corrected camera; ADD in the camera frame, as
``pcdet eval`` scores them).

``--kinect``: the recording with the default sensor model and mesh error (as ``tests/test_tracking.py`` makes its
recordings) instead of the idealised one; ``--sweep-deg``: the camera's sweep; ``--detector-seed``: the pipeline's
seed (RANSAC's draws). The table also gives, per object, the frames more than 5 mm off.

``--data DIR``: a real BOP recording of static objects instead (its first scene, its own ``models/``, no
targets), tracked and, beside it in the same run, detected frame by frame: per object the frames whose pose is
reported within ADD 0.1 d of the ground truth, the false reports, the tracks made, the full detections, seconds per
frame, and the camera's ATE against the camera the ground truth implies (the first listed object's poses: the
objects do not move, the first camera is the world).

Run:  python scripts/bench_tracking.py [--frames 60] [--objects 4] [--seed 2026] [--redetect-every 15]
                                      [--sweep-deg 90] [--kinect] [--detector-seed 0]
      python scripts/bench_tracking.py --data ../shared/data/linemod_cat
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from pcdet.config import PipelineConfig
from pcdet.datasets import open_recording
from pcdet.detector import Detector
from pcdet.library import ModelLibrary
from pcdet.metrics import add
from pcdet.synth import SynthConfig, synthesize
from pcdet.tracking import SceneFrames, Tracker, TrackingConfig, frames_by_scene
from pcdet.trajectory import ate_rmse

ROOT = Path(__file__).resolve().parent.parent


def _runs(frames: list[int]) -> str:
    """Frame indices as runs: [0, 1, 2, 5] -> "0-2, 5"."""
    out, i = [], 0
    while i < len(frames):
        j = i
        while j + 1 < len(frames) and frames[j + 1] == frames[j] + 1:
            j += 1
        out.append(f"{frames[i]}-{frames[j]}" if j > i else f"{frames[i]}")
        i = j + 1
    return ", ".join(out)


def real(data: Path, redetect_every: int, seed: int) -> None:
    """Tracking against detection alone on a real recording (``--data``; the module docstring)."""
    rec = open_recording(data)
    refs = next(iter(frames_by_scene(rec).values()))
    cfg = PipelineConfig(seed=seed)
    lib = ModelLibrary.from_folder(data / "models", cfg)
    gts = {r: rec.gt(r) for r in refs}
    runs = {}
    t0 = time.perf_counter()
    res = Tracker(Detector(lib, cfg), TrackingConfig(redetect_every=redetect_every)).run(SceneFrames(rec, refs))
    runs["tracking (pcdet run --track)"] = (res.detections, time.perf_counter() - t0, res)
    det = Detector(lib, cfg)
    t0 = time.perf_counter()
    found = [det.detect(rec.frame(r)).detections for r in refs]
    runs["detection alone (pcdet run)"] = (found, time.perf_counter() - t0, None)
    first = gts[refs[0]][0]["obj_id"]
    at = {r: next((g["T_cam_model"] for g in gts[r] if g["obj_id"] == first), None) for r in refs}
    print(f"{data.name}: {len(refs)} real frames, {len(lib)} model(s), no targets; tracking with full detection "
          f"every {redetect_every} frames and where tracking fails")
    print("| run | object | reported within ADD 0.1 d | false reports | tracks | full detections | s/frame | "
          "speed vs detection | camera ATE (mm) |")
    print("|---|---|---|---|---|---|---|---|---|")
    base = runs["detection alone (pcdet run)"][1]
    for name, (dets, secs, tr) in runs.items():
        for obj in sorted({g["obj_id"] for r in refs for g in gts[r]}):
            m = lib[lib.index_of(obj)]
            hit = false = n = 0
            for r, ds in zip(refs, dets):
                truth = [g["T_cam_model"] for g in gts[r] if g["obj_id"] == obj]
                n += len(truth)
                for d in (d for d in ds if d.obj_id == obj):
                    ok = any(add(d.T_cam_model, T, m.points) < 0.1 * m.diameter for T in truth)
                    hit, false = hit + ok, false + (not ok)
            tracks = sum(t.obj_id == obj for t in tr.tracks) if tr else ""
            full = sum(md == "detect" for md in tr.modes) if tr else len(refs)
            ate = ""
            if tr:
                keep = [i for i, r in enumerate(refs) if at[r] is not None and tr.camera_poses[i] is not None]
                gt = [at[refs[keep[0]]] @ np.linalg.inv(at[refs[i]]) for i in keep]
                ate = f"{ate_rmse([tr.camera_poses[i] for i in keep], gt) * 1000:.1f}"
            print(f"| {name} | {m.name} | {hit} of {n} | {false} | {tracks} | {full} | {secs / len(refs):.2f} | "
                  f"{base / secs:.2f}x | {ate} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--objects", type=int, default=4)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--redetect-every", type=int, default=15)
    ap.add_argument("--sweep-deg", type=float, default=90.0)
    ap.add_argument("--kinect", action="store_true", help="default sensor model and mesh error")
    ap.add_argument("--detector-seed", type=int, default=0)
    ap.add_argument("--data", type=Path, help="a real BOP recording of static objects (see above)")
    args = ap.parse_args()
    if args.data is not None:
        if not (args.data / "models").is_dir():
            raise SystemExit(f"error: {args.data / 'models'}: no models folder (a BOP dataset is expected)")
        return real(args.data, args.redetect_every, args.detector_seed)
    lib = ModelLibrary.from_folder(ROOT / "models")
    with tempfile.TemporaryDirectory() as tmp:
        # by default the idealised scenes (edge pixels dropped, exact meshes), where docs/measurements.md's first
        # figures come from
        ideal = {} if args.kinect else dict(sensor="structured_light", mesh_error=0)
        rec = open_recording(synthesize(lib, Path(tmp) / "seq", SynthConfig(
            scenes=1, objects=args.objects, sequence=args.frames, seed=args.seed, sweep_deg=args.sweep_deg,
            **ideal)))
        det = Detector(lib, PipelineConfig(seed=args.detector_seed))
        res = Tracker(det, TrackingConfig(redetect_every=args.redetect_every)).run(rec)
        refs = list(rec)
        cams = rec.camera_poses()
        W0 = np.linalg.inv(cams[refs[0]])
        print(f"{len(refs)} frames of 640x480, camera sweeping {args.sweep_deg:g} deg, full detection every "
              f"{args.redetect_every} frames; world = first camera frame")
        print("| object | frames seen | observed: largest error (mm) | median (mm) | frames over 5 mm | reported: "
              "largest ADD (mm) | median ADD (mm) |")
        print("|---|---|---|---|---|---|---|")
        for k, g0 in enumerate(rec.gt(refs[0])):
            pos = [(W0 @ cams[r] @ rec.gt(r)[k]["T_cam_model"])[:3, 3] for r in refs]
            tr = [t for t in res.tracks if t.obj_id == g0["obj_id"]]
            if not tr:
                print(f"| {lib.by_id(g0['obj_id']).name} | 0 | not tracked | | | | |")
                continue
            err = [np.linalg.norm(T[:3, 3] - pos[f]) * 1000 for f, T in zip(tr[0].frames, tr[0].poses)]
            over = [f for f, e in zip(tr[0].frames, err) if e > 5]
            pts = lib.by_id(g0["obj_id"]).points
            rep = [add(d.T_cam_model, rec.gt(refs[f])[k]["T_cam_model"], pts) * 1000
                   for f in tr[0].frames for d in res.detections[f] if d.obj_id == g0["obj_id"]]
            print(f"| {tr[0].model} | {len(err)} | {max(err):.2f} | {np.median(err):.2f} | "
                  f"{_runs(over) or 'none'} | {max(rep):.2f} | {np.median(rep):.2f} |")
        for mode in ("track", "detect"):
            s = [t for t, m in zip(res.seconds, res.modes) if m == mode]
            print(f"{mode} frames: {len(s)}, median {np.median(s) * 1000:.0f} ms = {1 / np.median(s):.1f} frames/s")


if __name__ == "__main__":
    main()
