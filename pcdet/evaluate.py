"""Score a BOP results file (or in-memory estimates) against a BOP dataset's ground truth."""
from __future__ import annotations

from dataclasses import dataclass

from .datasets.bop import BopDataset
from .library import ModelLibrary
from .metrics import VSD_TAUS, InstanceErrors, match_image, summarize, vsd
from .verify import render_model


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


def evaluate(ds: BopDataset, estimates: list[dict], library: ModelLibrary, with_vsd: bool = True) -> Evaluation:
    """estimates : rows as from ``io.bop.read_results_csv`` (scene_id, im_id, obj_id, score, T_cam_model).

    Estimates are matched to ground truth by MSSD (``metrics.match_image``); with ``with_vsd`` each matched
    pair is also rendered and scored by VSD against the image's depth."""
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
        errs, _ = match_image(gts, ests, points, cam.K, image_width=cam.width, scene_id=img.scene_id, im_id=img.im_id,
                              diameters=diam)
        if with_vsd and any(e.score is not None for e in errs):
            _add_vsd(errs, gts, ests, ds.frame(img), library)
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
    if not any(e.vsd is not None for e in errors):
        with_vsd = False
    overall = summarize(errors, diam, sum(fp.values()), width)
    per = {oid: summarize([e for e in errors if e.obj_id == oid], diam, fp.get(oid, 0), width)
           for oid in sorted({e.obj_id for e in errors})}
    return Evaluation(errors, fp, overall, per)


def _add_vsd(errs: list[InstanceErrors], gts: list[dict], ests: list[dict], frame, library: ModelLibrary) -> None:
    """Fill in ``vsd`` of the matched instances of one image by rendering both poses of each."""
    for e in errs:
        if e.est_index < 0:
            continue
        m = library.by_id(e.obj_id)
        d_est = render_model(m, ests[e.est_index]["T_cam_model"], frame.camera)
        d_gt = render_model(m, gts[e.gt_index]["T_cam_model"], frame.camera)
        e.vsd = vsd(d_est, d_gt, frame.depth, VSD_TAUS * m.diameter).tolist()
