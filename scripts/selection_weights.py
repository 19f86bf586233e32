"""Global selection's weights screened on several datasets at once, without running the detector again per setting.

Each frame is detected once with the pipeline as it is (no targets); the inputs of global selection are kept
(``Trace.selection``: the accepted poses' explained points, clutter, see-through costs and conflicts), and
``global_verify.select`` is run on them for every weight setting. Only the weights change, so the accepted poses
are the same in every row, and the pipeline's own weights give the detector's own detections.

A selected pose is correct when it lies within 0.1 d of a ground-truth instance of its object (ADD-S on BOP
datasets; ADD on the real cat frames, where only the cat counts and the cat's obj_id is 6). Recall: instances with
a correct selected pose; precision: correct selected poses / all selected. With the pipeline's own weights these
are the figures of ``bench_thirdparty.py``, ``bench_crowded.py`` and ``bench_library.py`` on the same data.

Datasets: ``--suite DIR[:PIPELINE]`` (a BOP dataset with its ``models/``; repeatable) and ``--cat 8,40`` (the
real LINEMOD cat frames with the 8- and 40-model libraries of ``bench_library.py``).

Run:  python scripts/selection_weights.py --suite SUITE[:default] [--cat 8,40] [--frames 0]
          [--weights "5,1;5,1.5;6,1"]      (clutter weight, see-through weight; duplicates keep the pipeline's)
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

from bench_library import build_libraries

from pcdet.config import load_pipeline
from pcdet.datasets import open_recording
from pcdet.detector import Detector, Trace
from pcdet.errors import InputError
from pcdet.global_verify import select
from pcdet.library import ModelLibrary
from pcdet.metrics import add, adds

CAT = 6


def collect(det: Detector, rec, frames: int, *, only: int | None = None, metric=adds) -> list[dict]:
    """Per frame: the selection inputs, which ground-truth instance each accepted pose is correct for (-1:
    none) and the number of instances. ``only``: count only that object's instances."""
    refs = list(rec)
    refs = refs[:frames] if frames > 0 else refs
    out = []
    for n, ref in enumerate(refs, 1):
        gts = [g for g in rec.gt(ref) if only is None or g["obj_id"] == only]
        tr = Trace()
        det.detect(rec.frame(ref), None, trace=tr)
        match = []
        for j in tr.accepted:
            m = det.library[tr.hypotheses[tr.refined[j]].model_index]
            T = tr.registrations[j].T_target_source
            errs = [(metric(T, g["T_cam_model"], m.points) / m.diameter, i) for i, g in enumerate(gts)
                    if g["obj_id"] == m.obj_id]
            best = min(errs, default=(1.0, -1))
            match.append(best[1] if best[0] < 0.1 else -1)
        if tr.selection is None:
            raise SystemExit("error: the pipeline does not select globally (verify.selection = 'threshold')")
        out.append({"selection": tr.selection, "match": match, "instances": len(gts)})
        print(f"\r  {n}/{len(refs)} frames", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return out


def score(frames: list[dict], w_dup: float, w_clutter: float, w_viol: float) -> tuple[int, int, int, int]:
    """(instances found, instances, correct selected, selected) with these weights."""
    found = inst = good = chosen = 0
    for f in frames:
        terms, conflicts = f["selection"]
        sel, _ = select(terms, w_dup, w_clutter, w_viol, conflicts=conflicts)
        m = [f["match"][i] for i in sel]
        found += len({x for x in m if x >= 0})
        inst += f["instances"]
        good += sum(x >= 0 for x in m)
        chosen += len(sel)
    return found, inst, good, chosen


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", action="append", default=[], help="BOP dataset DIR[:PIPELINE] (repeatable)")
    ap.add_argument("--cat", default="", help="real cat frames with these libraries: 8, 40 or 8,40")
    ap.add_argument("--cat-data", type=Path, default=Path(__file__).resolve().parent.parent.parent / "shared"
                    / "data" / "linemod_cat")
    ap.add_argument("--frames", type=int, default=0, help="first N frames of each dataset (0: all)")
    ap.add_argument("--weights", default="5,1;5,1.25;5,1.5;5,1.75;5,2;6,1;4.5,1.5",
                    help="settings 'clutter,see-through;...'")
    args = ap.parse_args()
    settings = [tuple(float(x) for x in s.split(",")) for s in args.weights.split(";") if s.strip()]
    if any(len(s) != 2 for s in settings):
        raise SystemExit(f"error: --weights {args.weights!r}: each setting is 'clutter,see-through'")
    libraries = [n.strip() for n in args.cat.split(",") if n.strip()]
    if any(n not in ("8", "40") for n in libraries):
        raise SystemExit(f"error: --cat {args.cat!r}: the libraries are 8 and 40")
    cached: list[tuple[str, float, list[dict]]] = []
    for spec in args.suite:
        folder, _, pipeline = spec.partition(":")
        cfg = load_pipeline(pipeline or "default")
        print(f"{folder} ({pipeline or 'default'})", file=sys.stderr)
        det = Detector(ModelLibrary.from_folder(Path(folder) / "models", cfg), cfg)
        cached.append((f"{Path(folder).name} ({pipeline or 'default'})", cfg.verify.duplicate_weight,
                       collect(det, open_recording(Path(folder)), args.frames)))
    if libraries:
        tmp = Path(tempfile.mkdtemp(prefix="pcdet-weights-"))
        try:
            lib8, lib40 = build_libraries(args.cat_data, tmp)
            cfg = load_pipeline("default")
            for n in libraries:
                print(f"real cat frames, {n} models", file=sys.stderr)
                det = Detector(ModelLibrary.from_folder(lib8 if n == "8" else lib40, cfg), cfg)
                cached.append((f"real cat, {n} models", cfg.verify.duplicate_weight,
                               collect(det, open_recording(args.cat_data), args.frames, only=CAT, metric=add)))
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    print("| clutter, see-through | " + " | ".join(name for name, _, _ in cached) + " |")
    print("|---|" + "---|" * len(cached))
    for wc, wv in settings:
        cells = []
        for _, w_dup, frames in cached:
            found, inst, good, chosen = score(frames, w_dup, wc, wv)
            cells.append(f"{found / max(inst, 1):.3f} / {good / max(chosen, 1):.3f}")
        print(f"| {wc:g}, {wv:g} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    try:
        main()
    except (InputError, FileNotFoundError) as e:  # a missing folder, an unreadable frame or pipeline file
        raise SystemExit(f"error: {e}") from None
