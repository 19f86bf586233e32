"""Score a BOP results file (or in-memory estimates) against a BOP dataset's ground truth.

Matching rule: each metric matches estimates to ground-truth instances on its own, per image and object, as
the BOP toolkit does (``metrics.match``: best score first, each estimate takes the unmatched instance it is
nearest to under that metric, if below the threshold at hand). So "recall ADD-S" counts instances matched by
ADD-S, and an estimate that is right up to an object's symmetry (``models_info.json``'s
``symmetries_discrete`` / ``symmetries_continuous``) is right by MSSD and MSPD.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .datasets.bop import BopDataset
from .errors import InputError
from .io.jsonfile import read_json
from .library import ModelLibrary
from .metrics import VSD_TAUS, ObjectErrors, match, object_errors, summarize, symmetry_transforms, vsd
from .verify import render_model


@dataclass
class Evaluation:
    """Errors per image and object, summaries overall and per object id, the estimates that matched no instance
    at ADD-S < 0.1 d (per object id), and warnings about estimates that were left out (with their lines)."""

    objects: list[ObjectErrors]
    false_positives: dict[int, int]
    overall: dict
    per_object: dict[int, dict]
    warnings: list[str] = field(default_factory=list)

    def instances(self) -> list[dict]:
        """Per ground-truth instance, the lowest error any estimate of its object in its image reaches, per
        metric (None without estimates): what the nearest guess was, independent of matching."""
        out = []
        for o in self.objects:
            for j, vf in enumerate(o.visib_fract):
                row = {"scene_id": o.scene_id, "im_id": o.im_id, "obj_id": o.obj_id, "gt_index": j,
                       "visib_fract": vf}
                for k in ("add", "adds", "mssd", "mspd"):
                    col = o.errors[k][:, j]
                    row[k] = float(col.min()) if len(col) else None
                out.append(row)
        return out

    def to_dict(self) -> dict:
        """Summaries, false positives, warnings and per-instance nearest errors, as ``pcdet eval --json`` writes
        them."""
        return {"overall": self.overall, "per_object": {str(k): v for k, v in self.per_object.items()},
                "false_positives": {str(k): v for k, v in self.false_positives.items()},
                "warnings": self.warnings, "instances": self.instances()}


def load_symmetries(models_dir, library: ModelLibrary, max_step: float = 0.01) -> dict[int, list[np.ndarray]]:
    """``{obj_id: [(4, 4) model-frame transforms, m]}`` from ``models_dir/models_info.json`` (BOP); empty when
    the folder has none."""
    p = Path(models_dir) / "models_info.json" if models_dir is not None else None
    if p is None or not p.is_file():
        return {}
    info = read_json(p)
    out = {}
    for m in library:
        entry = info.get(str(m.obj_id), {})
        try:
            syms = symmetry_transforms(entry, max_step)
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"object {m.obj_id}: malformed symmetries ({e})", p) from None
        if len(syms) > 1:
            out[m.obj_id] = syms
    return out


def evaluate(ds: BopDataset, estimates: list[dict], library: ModelLibrary, *, with_vsd: bool = True,
             symmetries: dict[int, list[np.ndarray]] | None = None, source=None) -> Evaluation:
    """estimates : rows as from ``io.bop.read_results_csv`` (scene_id, im_id, obj_id, score, T_cam_model, and
    ``line``, the file line, when read from a file; ``source`` names that file in messages).

    An estimate of an object that is not among the models is an error (``InputError``); estimates for images
    the dataset does not hold are left out with a warning that lists their lines. With ``with_vsd`` every
    estimate and instance of an image is rendered, for VSD against the image's depth.

    When ``ds`` is restricted to a BOP target list (``BopDataset.restrict_to``), the scoring is BOP'19's: only
    the listed images and objects count, an instance less than 10 % visible is neither found nor missed
    (``BopDataset.scored_gt``), and of each listed object only its ``inst_count`` best-scoring estimates are
    scored; estimates for images the list does not name are left out with a warning."""
    symmetries = symmetries or {}
    models = {m.obj_id: m for m in library}
    listed = ds.target_list
    known_images = {(img.scene_id, img.im_id) for img in ds}
    by_img: dict[tuple[int, int], list[dict]] = {}
    stray: list[str] = []
    for n, e in enumerate(estimates):
        where = f"line {e['line']}" if e.get("line") is not None else f"estimate {n}"
        if e["obj_id"] not in models:
            raise InputError(f"{where}: obj_id {e['obj_id']} is not among the models ({sorted(models)})", source)
        key = (e["scene_id"], e["im_id"])
        if key not in known_images:
            stray.append(f"{where} (scene {key[0]} image {key[1]})")
            continue
        by_img.setdefault(key, []).append(e)
    warnings = []
    if stray:
        where = "the target list does not name" if listed is not None else "the dataset does not hold"
        warnings.append(f"{len(stray)} estimate(s) for images {where} were left out: "
                        + ", ".join(stray[:10]) + (", ..." if len(stray) > 10 else ""))
    objects: list[ObjectErrors] = []
    for img in ds:
        gts = ds.scored_gt(img)
        ests = by_img.get((img.scene_id, img.im_id), [])
        cam = ds.camera(img)
        frame = ds.frame(img) if with_vsd else None
        wanted = listed[(img.scene_id, img.im_id)] if listed is not None else None
        oids = sorted(wanted if wanted is not None else {g["obj_id"] for g in gts} | {e["obj_id"] for e in ests})
        for oid in oids:
            m = models.get(oid)
            if m is None:
                continue  # ground truth of an object the library lacks: nothing to score it with
            g_o = [g for g in gts if g["obj_id"] == oid]
            e_o = [e for e in ests if e["obj_id"] == oid]
            if wanted is not None:  # BOP'19: the inst_count best estimates (scored_gt: the visible instances)
                e_o = sorted(e_o, key=lambda e: -e["score"])[:wanted[oid]]
            o = object_errors(g_o, e_o, m.points, cam.K, m.diameter, symmetries=symmetries.get(oid),
                              scene_id=img.scene_id, im_id=img.im_id, obj_id=oid)
            if frame is not None:
                o.errors["vsd"] = _vsd(g_o, e_o, m, frame)
            objects.append(o)
    width = ds.camera(ds.images[0]).width if len(ds) else 640
    fp: dict[int, int] = {}
    for o in objects:
        if len(o.scores):
            unmatched = len(o.scores) - len(match(o.errors["adds"], o.scores, 0.1 * o.diameter))
            if unmatched:
                fp[o.obj_id] = fp.get(o.obj_id, 0) + unmatched
    overall = summarize(objects, width)
    per = {oid: summarize([o for o in objects if o.obj_id == oid], width)
           for oid in sorted({o.obj_id for o in objects})}
    return Evaluation(objects, fp, overall, per, warnings)


def _vsd(gts: list[dict], ests: list[dict], model, frame) -> np.ndarray:
    """(E, G, len(VSD_TAUS)) VSD of every estimate against every instance, each rendered once."""
    d_est = [render_model(model, e["T_cam_model"], frame.camera) for e in ests]
    d_gt = [render_model(model, g["T_cam_model"], frame.camera) for g in gts]
    out = np.ones((len(ests), len(gts), len(VSD_TAUS)))
    for i, de in enumerate(d_est):
        for j, dg in enumerate(d_gt):
            out[i, j] = vsd(de, dg, frame.depth, VSD_TAUS * model.diameter)
    return out
