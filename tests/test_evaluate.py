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
    assert sum(s["instances"] for s in ev.per_object.values()) == 9 and not ev.false_positives and not ev.warnings


def test_a_moved_estimate_and_a_false_positive(synth_small, library):
    """One estimate moved 0.3 d away (beyond ADD 0.1 d) and one detection of an object the image does not hold:
    recall 8/9, precision 8/10, both counted as false positives for their objects; AR_MSSD counts the moved
    one at the 4 thresholds above 0.3 d (0.35 .. 0.5 d)."""
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
    assert ev.false_positives == {absent: 1, m.obj_id: 1} if absent != m.obj_id else {absent: 2}
    moved = next(r for r in ev.instances() if r["scene_id"] == img.scene_id and r["obj_id"] == m.obj_id)
    assert moved["add"] == pytest.approx(0.3 * m.diameter) and moved["mssd"] == pytest.approx(0.3 * m.diameter)
    assert ev.overall["ar_mssd"] == pytest.approx((8 + 4 / 10) / 9)
    assert "ar_vsd" not in ev.overall


def test_malformed_rows_name_the_file_and_line(synth_small, library, tmp_path):
    """NaN, a non-rotation R, an unknown object: errors naming file and line; an image the dataset does not
    hold: left out with a warning naming the line."""
    from pcdet.errors import InputError
    from pcdet.io.bop import read_results_csv

    good = "1,0,1,0.5,1 0 0 0 1 0 0 0 1,0 0 500,-1\n"
    head = "scene_id,im_id,obj_id,score,R,t,time\n"
    p = tmp_path / "r.csv"
    for bad, words in (("1,0,1,0.5,1 0 0 0 1 0 0 0 1,0 nan 500,-1\n", "line 3: R, t or score is not a finite"),
                       ("1,0,1,0.5,1 0 0 0 1 0 0 0 2,0 0 500,-1\n", "line 3: R is not a rotation"),
                       ("1,0,1,0.5,1 0 0 0 -1 0 0 0 1,0 0 500,-1\n", "line 3: R is not a rotation")):
        p.write_text(head + good + bad)
        with pytest.raises(InputError, match=words):
            read_results_csv(p)
    ds = BopDataset(synth_small)
    p.write_text(head + good + "1,0,99,0.5,1 0 0 0 1 0 0 0 1,0 0 500,-1\n")
    with pytest.raises(InputError, match=r"r\.csv: line 3: obj_id 99 is not among the models"):
        evaluate(ds, read_results_csv(p), library, with_vsd=False, source=p)
    p.write_text(head + good + "7,0,1,0.5,1 0 0 0 1 0 0 0 1,0 0 500,-1\n")
    ev = evaluate(ds, read_results_csv(p), library, with_vsd=False, source=p)
    assert ev.warnings == ["1 estimate(s) for images the dataset does not hold were left out: line 3 (scene 7 "
                           "image 0)"]
    assert ev.overall["estimates"] == 1
