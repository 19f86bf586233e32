"""Global selection's weights screened on several datasets at once, without running the detector again per setting.

Each frame is detected once with the pipeline as it is (no targets); the inputs of global selection are kept
(``Trace.selection``: the accepted poses' explained points, clutter, see-through costs and conflicts), and
``global_verify.select`` is run on them for every weight setting. Only the weights change, so the accepted poses
are the same in every row, and the pipeline's own weights give the detector's own detections.

Each setting's selected poses are scored by ``pcdet.evaluate`` (BOP matching, one estimate per instance, as
``bench_thirdparty.py`` and ``bench_crowded.py`` score them): recall at ADD-S < 0.1 d and precision, the share of
selected poses matched. On the real cat frames recall and precision are taken at ADD < 0.1 d (the cat is not
symmetric; ``bench_library.py`` counts the same way), and every pose of another model is a false positive.

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
from pcdet.datasets.bop import BopDataset
from pcdet.detector import Detector, Trace
from pcdet.errors import InputError
from pcdet.evaluate import evaluate
from pcdet.global_verify import select
from pcdet.library import ModelLibrary

def collect(det: Detector, ds: BopDataset) -> list[dict]:
    """Per image of ``ds``: the selection inputs (``Trace.selection``) and the accepted poses, in their order, as
    estimates (``evaluate``'s rows)."""
    out = []
    for n, img in enumerate(ds, 1):
        tr = Trace()
        det.detect(ds.frame(img), None, trace=tr)
        if tr.selection is None:
            raise SystemExit("error: the pipeline does not select globally (verify.selection = 'threshold')")
        poses = [{"scene_id": img.scene_id, "im_id": img.im_id, "score": tr.verifications[j].score,
                  "obj_id": det.library[tr.hypotheses[tr.refined[j]].model_index].obj_id,
                  "T_cam_model": tr.registrations[j].T_target_source} for j in tr.accepted]
        out.append({"selection": tr.selection, "poses": poses})
        print(f"\r  {n}/{len(ds)} frames", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return out


def score(ds: BopDataset, library: ModelLibrary, frames: list[dict], metric: str, w_dup: float, w_clutter: float,
          w_viol: float) -> tuple[float, float]:
    """(recall, precision) at ``metric`` ('add' or 'adds') < 0.1 d of the poses selected with these weights."""
    ests = []
    for f in frames:
        terms, conflicts = f["selection"]
        chosen, _ = select(terms, w_dup, w_clutter, w_viol, conflicts=conflicts)
        ests += [f["poses"][i] for i in chosen]
    ov = evaluate(ds, ests, library, with_vsd=False).overall
    recall = ov[f"recall_{metric}"]
    return recall, recall * ov["instances"] / ov["estimates"] if ov["estimates"] else 0.0


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
    cached = []  # (column, dataset, library, metric, duplicate weight, frames)
    for spec in args.suite:
        folder, _, pipeline = spec.partition(":")
        cfg = load_pipeline(pipeline or "default")
        print(f"{folder} ({pipeline or 'default'})", file=sys.stderr)
        ds, lib = _first(BopDataset(Path(folder)), args.frames), ModelLibrary.from_folder(Path(folder) / "models", cfg)
        cached.append((f"{Path(folder).name} ({pipeline or 'default'})", ds, lib, "adds", cfg.verify.duplicate_weight,
                       collect(Detector(lib, cfg), ds)))
    if libraries:
        tmp = Path(tempfile.mkdtemp(prefix="pcdet-weights-"))
        try:
            lib8, lib40 = build_libraries(args.cat_data, tmp)
            cfg = load_pipeline("default")
            ds = _first(BopDataset(args.cat_data), args.frames)
            for n in libraries:
                print(f"real cat frames, {n} models", file=sys.stderr)
                lib = ModelLibrary.from_folder(lib8 if n == "8" else lib40, cfg)
                cached.append((f"real cat, {n} models", ds, lib, "add", cfg.verify.duplicate_weight,
                               collect(Detector(lib, cfg), ds)))
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    print("| clutter, see-through | " + " | ".join(c[0] for c in cached) + " |")
    print("|---|" + "---|" * len(cached))
    for wc, wv in settings:
        cells = [score(ds, lib, frames, metric, w_dup, wc, wv) for _, ds, lib, metric, w_dup, frames in cached]
        print(f"| {wc:g}, {wv:g} | " + " | ".join(f"{r:.3f} / {p:.3f}" for r, p in cells) + " |")


def _first(ds: BopDataset, frames: int) -> BopDataset:
    """``ds`` cut to its first ``frames`` images (0: all), so that evaluation counts only those."""
    if frames > 0:
        ds.images = ds.images[:frames]
    return ds

if __name__ == "__main__":
    try:
        main()
    except (InputError, FileNotFoundError) as e:  # a missing folder, an unreadable frame or pipeline file
        raise SystemExit(f"error: {e}") from None
