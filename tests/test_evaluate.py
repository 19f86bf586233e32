"""Scoring a results list against a BOP dataset: perfect estimates, a known miss, a false positive."""
from pathlib import Path

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


def _target_list(path, entries):
    import json

    path.write_text(json.dumps([{"scene_id": s, "im_id": i, "obj_id": o, "inst_count": c} for s, i, o, c in entries]))
    return path


def test_a_bop_target_list_restricts_images_and_targets(synth_small, tmp_path):
    """restrict_to keeps the listed images only, in split order, and their targets are the list's; a list that
    is missing, malformed, names an object twice or an image the split lacks is refused naming the file."""
    import shutil

    from pcdet.errors import InputError

    ds = BopDataset(synth_small)
    objs = {img: sorted(ds.targets(img)) for img in ds}
    first, last = ds.images[0], ds.images[-1]
    path = _target_list(tmp_path / "t.json", [(last.scene_id, 0, objs[last][0], 1),
                                              (first.scene_id, 0, objs[first][1], 2)])
    ds.restrict_to(str(path))
    assert ds.images == [first, last] and len(ds) == 2
    assert ds.targets(first) == {objs[first][1]: 2} and ds.targets(last) == {objs[last][0]: 1}
    for text, words in (('{"scene_id": 1}', "JSON list"), ('[{"scene_id": 1, "im_id": 0}]', "entry 0 is not"),
                        ('[{"scene_id": 1, "im_id": 0, "obj_id": 2, "inst_count": 0}]', "inst_count >= 1"),
                        ('[{"scene_id": 1, "im_id": 0, "obj_id": 2, "inst_count": 1}, '
                         '{"scene_id": 1, "im_id": 0, "obj_id": 2, "inst_count": 1}]', "lists object 2 twice"),
                        ('[{"scene_id": 9, "im_id": 0, "obj_id": 2, "inst_count": 1}]', "scene 9 image 0"),
                        ("[]", "empty")):
        (tmp_path / "bad.json").write_text(text)
        with pytest.raises(InputError) as e:
            BopDataset(synth_small).restrict_to(str(tmp_path / "bad.json"))
        assert "bad.json" in str(e.value) and words in str(e.value), (text, str(e.value))
    copy = tmp_path / "copy"
    shutil.copytree(synth_small, copy)
    with pytest.raises(InputError) as e:
        BopDataset(copy).restrict_to("bop19")
    assert "test_targets_bop19.json" in str(e.value) and "not found" in str(e.value)
    _target_list(copy / "test_targets_bop19.json", [(first.scene_id, 0, objs[first][0], 1)])
    ds = BopDataset(copy)
    ds.restrict_to("bop19")
    assert ds.images == [first]


def test_bop19_scoring_with_a_target_list(synth_small, library, tmp_path):
    """Scored on a target list as BOP'19 scores: an instance under 10 % visible is neither found nor missed, only
    the inst_count best-scoring estimates of an object count (a wrong one scored higher displaces the right one),
    and listed objects only. Without the list the same estimates find every instance."""
    import json
    import shutil

    copy = tmp_path / "ds"
    shutil.copytree(synth_small, copy)
    ds = BopDataset(copy)
    img = ds.images[0]
    info_path = ds.scene_dir(img.scene_id) / "scene_gt_info.json"
    info = json.loads(info_path.read_text())
    info[str(img.im_id)][0]["visib_fract"] = 0.05  # the image's first instance: almost hidden
    info_path.write_text(json.dumps(info))
    ds = BopDataset(copy)
    gts = ds.gt(img)
    hidden, other = gts[0]["obj_id"], gts[1]["obj_id"]
    ests = [e for e in _gt_estimates(ds) if not (e["scene_id"] == img.scene_id and e["obj_id"] == hidden)]
    T = next(e for e in ests if e["scene_id"] == img.scene_id and e["obj_id"] == other)["T_cam_model"].copy()
    T[0, 3] += library.by_id(other).diameter  # one diameter off, scored above the right estimate
    ests.append({"scene_id": img.scene_id, "im_id": img.im_id, "obj_id": other, "score": 2.0, "T_cam_model": T})
    plain = evaluate(ds, ests, library, with_vsd=False).overall
    assert plain["instances"] == 9 and plain["recall_add"] == pytest.approx(8 / 9)  # the hidden one is missed
    listed = [(i.scene_id, i.im_id, o, n) for i in ds.images for o, n in ds.targets(i).items()]
    ds.restrict_to(str(_target_list(tmp_path / "t.json", listed)))
    bop = evaluate(ds, ests, library, with_vsd=False).overall
    assert bop["instances"] == 8 and bop["recall_add"] == pytest.approx(7 / 8)  # the displaced one is missed
    # a list naming only the hidden object's image and the other object: that one instance is scored
    ds = BopDataset(copy)
    ds.restrict_to(str(_target_list(tmp_path / "t2.json", [(img.scene_id, img.im_id, other, 1)])))
    ev = evaluate(ds, ests + [{"scene_id": ds.images[0].scene_id + 1, "im_id": 0, "obj_id": other, "score": 1.0,
                               "T_cam_model": T}], library, with_vsd=False)
    assert ev.overall["instances"] == 1 and ev.overall["recall_add"] == 0.0
    assert "images the target list does not name" in ev.warnings[0]


def test_bop_annotations_as_estimates_score_one_on_every_metric(tmp_path, library):
    """The ground truth written as a results file the way real BOP annotations are (R orthonormal only to about
    2e-3, as LM-O's driller), with symmetric objects turned by their own declared symmetries: a box turned 180
    degrees about its z axis (``symmetries_discrete``) and a cylinder turned about its axis
    (``symmetries_continuous``). Every metric is 1.0, and the output says once that R was re-orthonormalised."""
    import json

    import trimesh
    from scipy.spatial.transform import Rotation
    from typer.testing import CliRunner

    from pcdet.cli import app
    from pcdet.io.bop import results_row, write_results_csv
    from pcdet.library import ModelLibrary
    from pcdet.synth import SynthConfig, synthesize

    folder = tmp_path / "models"
    folder.mkdir()
    trimesh.creation.box(extents=(60, 40, 30)).export(folder / "obj_000001.ply")
    trimesh.creation.cylinder(radius=25, height=70, sections=128).export(folder / "obj_000002.ply")
    (folder / "obj_000003.ply").write_bytes(Path(library.by_id(1).path).read_bytes())  # the bracket: no symmetry
    lib = ModelLibrary.from_folder(folder, units="mm")
    ds_dir = synthesize(lib, tmp_path / "ds", SynthConfig(scenes=2, objects=3, seed=3))
    info_path = ds_dir / "models" / "models_info.json"
    info = json.loads(info_path.read_text())
    flip_z = np.diag([-1.0, -1.0, 1.0, 1.0])
    info["1"]["symmetries_discrete"] = [flip_z.reshape(-1).tolist()]
    info["2"]["symmetries_continuous"] = [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]
    info_path.write_text(json.dumps(info))
    turn = {1: flip_z, 2: np.eye(4)}
    turn[2][:3, :3] = Rotation.from_rotvec([0, 0, 1.0]).as_matrix()
    ds = BopDataset(ds_dir)
    rows, written = [], 0
    for img in ds:
        for g in ds.gt(img):
            T = g["T_cam_model"] @ turn.get(g["obj_id"], np.eye(4))
            T[:3, :3] = np.round(T[:3, :3] * (1 + 1e-3), 4)  # stored to a few decimals and 2e-3 off orthonormal
            rows.append(results_row(img.scene_id, img.im_id, g["obj_id"], 1.0, T, -1))
            written += 1
    write_results_csv(tmp_path / "r.csv", rows)
    res = CliRunner().invoke(app, ["eval", str(ds_dir), str(tmp_path / "r.csv"), "--json", str(tmp_path / "e.json")])
    assert res.exit_code == 0, res.output
    assert res.output.count("re-orthonormalised") == 1 and f"in {written} row(s)" in res.output
    overall = json.loads((tmp_path / "e.json").read_text())["overall"]
    assert overall["instances"] == overall["estimates"] == 6
    for k in ("recall_add", "recall_adds", "precision_adds", "ar_mssd", "ar_mspd", "ar_vsd", "ar"):
        assert overall[k] == pytest.approx(1.0), (k, overall)


def test_r_far_from_a_rotation_is_refused(tmp_path):
    """Beyond the tolerance that real annotations need (an R 0.05 off, a reflection) a row is refused."""
    from pcdet.errors import InputError
    from pcdet.io.bop import read_results_csv

    head = "scene_id,im_id,obj_id,score,R,t,time\n"
    p = tmp_path / "r.csv"
    for R in ("1.05 0 0 0 1 0 0 0 1", "-1 0 0 0 1 0 0 0 1"):
        p.write_text(head + f"1,0,1,0.5,{R},0 0 500,-1\n")
        with pytest.raises(InputError, match="line 2: R is not a rotation"):
            read_results_csv(p)
    p.write_text(head + "1,0,1,0.5,1.002 0 0 0 1 0 0 0 1,0 0 500,-1\n")
    (row,) = read_results_csv(p)
    assert row["R_deviation"] == pytest.approx(0.002 * 2.002)
    np.testing.assert_allclose(row["T_cam_model"][:3, :3], np.eye(3), atol=1e-12)
