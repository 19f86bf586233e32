"""Scoring a results list against a BOP dataset: perfect estimates, a known miss, a false positive."""
import numpy as np
import pytest

from pcdet.datasets.bop import BopDataset
from pcdet.evaluate import evaluate


def _gt_estimates(ds):
    return [{"scene_id": img.scene_id, "im_id": img.im_id, "obj_id": g["obj_id"], "score": 1.0,
             "T_cam_model": g["T_cam_model"]} for img in ds for g in ds.gt(img)]


def test_ground_truth_as_estimates_scores_perfectly(synth_small, library):
    ds = BopDataset(synth_small)
    ev = evaluate(ds, _gt_estimates(ds), library)
    o = ev.overall
    assert o["instances"] == o["estimates"] == 9
    for k in ("recall_add", "recall_adds", "precision_adds", "ar_mssd", "ar_mspd", "ar_vsd", "ar"):
        assert o[k] == pytest.approx(1.0), k
    assert sum(s["instances"] for s in ev.per_object.values()) == 9 and not ev.false_positives


def test_a_moved_estimate_and_a_false_positive(synth_small, library):
    """One estimate moved 0.3 d away (beyond ADD 0.1 d, within the MSSD matching bound 0.5 d) and one
    detection of an object the image does not hold: recall 8/9, precision 8/10, the false positive counted
    for its object."""
    ds = BopDataset(synth_small)
    ests = _gt_estimates(ds)
    m = library.by_id(ests[0]["obj_id"])
    T = ests[0]["T_cam_model"].copy()
    T[0, 3] += 0.3 * m.diameter
    ests[0] = dict(ests[0], T_cam_model=T)
    img = ds.images[0]
    absent = next(x.obj_id for x in library if x.obj_id not in ds.targets(img))
    ests.append({"scene_id": img.scene_id, "im_id": img.im_id, "obj_id": absent, "score": 0.5,
                 "T_cam_model": np.eye(4)})
    ev = evaluate(ds, ests, library, with_vsd=False)
    assert ev.overall["recall_add"] == pytest.approx(8 / 9)
    assert ev.overall["precision_adds"] == pytest.approx(8 / 10)
    assert ev.false_positives == {absent: 1}
    moved = next(e for e in ev.errors if e.scene_id == img.scene_id and e.gt_index == 0)
    assert moved.add == pytest.approx(0.3 * m.diameter) and moved.mssd == pytest.approx(0.3 * m.diameter)
    assert "ar_vsd" not in ev.overall
