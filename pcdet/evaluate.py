"""Score a BOP results file (or in-memory estimates) against a BOP dataset's ground truth."""
from __future__ import annotations

from dataclasses import dataclass


from .datasets.bop import BopDataset
from .metrics import InstanceErrors, match_image, summarize
from .model import ModelLibrary


@dataclass
class Evaluation:
    """Per-instance errors, false positives, and summaries overall and per object id."""

    errors: list[InstanceErrors]
    false_positives: dict[int, int]
    overall: dict
    per_object: dict[int, dict]

    def to_dict(self) -> dict:
        return {"overall": self.overall, "per_object": {str(k): v for k, v in self.per_object.items()},
                "instances": [vars(e) for e in self.errors]}


def evaluate(ds: BopDataset, estimates: list[dict], library: ModelLibrary) -> Evaluation:
    """estimates : rows as from ``read_bop_csv`` (scene_id, im_id, obj_id, score, T_cam_model)."""
    points = {m.obj_id: m.points for m in library}
    diam = {m.obj_id: m.diameter for m in library}
    by_img: dict[tuple[int, int], list[dict]] = {}
    for e in estimates:
        by_img.setdefault((e["scene_id"], e["im_id"]), []).append(e)
    errors: list[InstanceErrors] = []
    fp: dict[int, int] = {}
    for img in ds:
        gts = ds.gt(img)
        ests = by_img.get((img.scene_id, img.im_id), [])
        cam = ds.camera(img)
        errs, _ = match_image(gts, ests, points, cam.K, cam.width, scene_id=img.scene_id, im_id=img.im_id)
        errors += errs
        matched = {}
        for e in errs:
            if e.score is not None:
                matched[e.obj_id] = matched.get(e.obj_id, 0) + 1
        for oid in {e["obj_id"] for e in ests}:
            n = sum(1 for e in ests if e["obj_id"] == oid) - matched.get(oid, 0)
            if n:
                fp[oid] = fp.get(oid, 0) + n
    width = ds.camera(ds.images[0]).width if len(ds) else 640
    overall = summarize(errors, diam, sum(fp.values()), width)
    per = {oid: summarize([e for e in errors if e.obj_id == oid], diam, fp.get(oid, 0), width)
           for oid in sorted({e.obj_id for e in errors})}
    return Evaluation(errors, fp, overall, per)
