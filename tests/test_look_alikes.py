"""Look-alike models (one shape at several sizes): which models form a family, and how a pose moves between them;
and in the detector, that a family is grouped once and each member is still refined and verified on its own."""
import numpy as np
import pytest
import trimesh

from pcdet.align import transform
from pcdet.config import PipelineConfig
from pcdet.datasets.bop import BopDataset
from pcdet.detector import Detector
from pcdet.diagnose import diagnose_frame
from pcdet.library import ModelLibrary
from pcdet.look_alikes import MAX_SCALE, look_alike_families, transfer
from pcdet.metrics import adds

from .conftest import MODELS, random_pose, shared


def _samples(mesh: trimesh.Trimesh, spacing: float = 0.004) -> np.ndarray:
    """(N, 3) surface samples about ``spacing`` apart, the same density at every size (as model points are)."""
    n = int(mesh.area / spacing**2)
    return trimesh.sample.sample_surface_even(mesh, n, seed=0)[0]


def _families(meshes):
    pts = [_samples(m) for m in meshes]
    centres = [(p.max(0) + p.min(0)) / 2 for p in pts]
    diam = [float(np.linalg.norm(np.ptp(p, axis=0))) for p in pts]
    return look_alike_families(pts, centres, diam, 0.003)


def _scaled(mesh: trimesh.Trimesh, s: float) -> trimesh.Trimesh:
    m = mesh.copy()
    m.apply_scale(s)
    return m


def test_scaled_copies_form_one_family_around_the_middle_size_in_any_order():
    """Copies of a box scaled by 0.92 and 1.08 join it, with the box (the middle size) grouped for all three; a
    cylinder of about the same size, the box turned in its own frame, and a copy 1.4 times larger (beyond
    ``MAX_SCALE`` of every other size) stay on their own. Listing the models in another order changes nothing but
    the indices."""
    box = trimesh.creation.box((0.08, 0.05, 0.03))
    turned = box.copy()
    turned.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 0, 1]))
    meshes = [_scaled(box, 0.92), trimesh.creation.cylinder(0.03, 0.08), box, turned, _scaled(box, 1.08),
              _scaled(box, 1.4)]
    assert 1.4 / 1.08 > MAX_SCALE
    fams = _families(meshes)
    expected = [(2, (0, 2, 4)), (1, (1,)), (3, (3,)), (5, (5,))]
    assert [(f.representative, f.members) for f in fams] == expected
    order = [5, 4, 3, 2, 1, 0]  # the same models listed backwards: the box is at 3, its copies at 1 and 5
    back = _families([meshes[i] for i in order])
    assert [(f.representative, f.members) for f in back] == [(0, (0,)), (3, (1, 3, 5)), (2, (2,)), (4, (4,))]


def test_distance_zero_keeps_every_model_on_its_own():
    """Two models whose samples are exactly one another's scaled by 1.08 (mean distance 0) are look-alikes at any
    positive distance, and each on its own at 0."""
    p = _samples(trimesh.creation.box((0.08, 0.05, 0.03)))
    pts, centres = [p, 1.08 * p], [np.zeros(3)] * 2
    diam = [float(np.linalg.norm(np.ptp(q, axis=0))) for q in pts]
    assert [f.members for f in look_alike_families(pts, centres, diam, 1e-9)] == [(0, 1)]
    assert [f.members for f in look_alike_families(pts, centres, diam, 0.0)] == [(0,), (1,)]


def test_transfer_puts_the_members_box_centre_where_the_representatives_was(rng):
    """A pose of the representative, moved to a member whose box centre is elsewhere in its own frame, keeps the
    rotation and maps the member's centre to the scene point the representative's centre was at (to 1e-12 m)."""
    T = random_pose(rng)
    c_rep, c_member = np.array([0.01, -0.02, 0.03]), np.array([0.011, -0.0216, 0.0324])
    Tm = transfer(T, c_rep, c_member)
    np.testing.assert_array_equal(Tm[:3, :3], T[:3, :3])
    np.testing.assert_allclose(transform(Tm, c_member[None]), transform(T, c_rep[None]), atol=1e-12)


def _with_copies(tmp_path, scales=(0.92, 1.08)):
    """The six shipped parts and, for the first, copies at ``scales`` (ids 101, 201, ...), as a BOP model folder."""
    import json
    import shutil

    folder = tmp_path / "models"
    shutil.copytree(MODELS, folder)
    info = json.loads((folder / "models_info.json").read_text())
    base = trimesh.load(folder / "obj_000001.ply", process=False)
    for n, s in enumerate(scales, start=1):
        _scaled(base, s).export(folder / f"obj_{100 * n + 1:06d}.ply")
        info[str(100 * n + 1)] = {**info["1"], "name": f"bracket x{s}", "diameter": info["1"]["diameter"] * s}
    (folder / "models_info.json").write_text(json.dumps(info))
    return folder


@pytest.mark.slow
def test_a_family_is_grouped_once_and_each_size_verified_on_its_own(tmp_path, synth_small, library):
    """With two scaled copies of the bracket in the library, grouping runs for the six parts only (eight with
    ``grouping.look_alike = 0``), and so do the coarse ICPs: the same models from the same poses as with the six
    parts alone (the copies take the bracket's coarse poses). Every object the six-part library finds is found
    again as the same model within 5 mm ADD-S, and no scaled bracket is reported (they are only in the
    library)."""
    cfg = PipelineConfig(seed=4)
    big = ModelLibrary.from_folder(_with_copies(tmp_path), cfg)
    ds = BopDataset(synth_small)
    ref = next(r for r in ds.images if any(g["obj_id"] == 1 for g in ds.gt(r)))
    frame = ds.frame(ref)
    calls, coarse, found = {}, {}, {}
    for name, lib, c in (("parts", library, cfg), ("families", big, cfg),
                         ("each", big, cfg.replace(grouping={"look_alike": 0.0}))):
        det = Detector(lib, c, workers=1)
        group, coarse_icp = det.grouper.group, det._coarse_icp
        calls[name], coarse[name] = [], []
        det.grouper.group = lambda view, pm, *a, _n=calls[name], _g=group, **kw: _n.append(pm.model.obj_id) or _g(
            view, pm, *a, **kw)
        det._coarse_icp = lambda scene, poses, _n=coarse[name], _f=coarse_icp, _lib=lib: _n.extend(
            (_lib[mi].obj_id, T) for mi, T in poses) or _f(scene, poses)
        found[name] = det.detect(frame).detections
    plain, with_copies = found["parts"], found["families"]
    assert sorted(calls["families"]) == sorted(calls["parts"]) == [1, 2, 3, 4, 5, 6]
    assert coarse["parts"] and [o for o, _ in coarse["families"]] == [o for o, _ in coarse["parts"]]
    assert all(np.array_equal(a, b) for (_, a), (_, b) in zip(coarse["families"], coarse["parts"]))
    assert {o for o, _ in coarse["each"]} > {1, 101, 201}  # each on its own: the copies' own coarse ICPs
    assert sorted(calls["each"]) == [1, 2, 3, 4, 5, 6, 101, 201]
    assert plain and all(d.obj_id < 100 for d in with_copies), [d.obj_id for d in with_copies]
    for d in plain:
        m = library[library.index_of(d.obj_id)]
        assert any(e.obj_id == d.obj_id and adds(e.T_cam_model, d.T_cam_model, m.points) < 0.005
                   for e in with_copies), (d, with_copies)


@pytest.mark.slow
def test_a_scaled_copy_in_view_is_found_as_a_member_of_its_family(tmp_path):
    """8 scenes each holding only the bracket scaled by 1.08, with the bracket and its 0.92 and 1.08 copies in the
    library: in every scene the one detection is a member of the family, on the object: within ADD-S 0.05 d of the
    truth, measured with the 1.08 copy's own points (a member 8 or 16 % off in size, laid onto the object, leaves
    a mean gap of about 0.03 d; any other model or place leaves far more). Which member is kept is not asserted: at
    this range the outline tells sizes 8 % apart only by chance (the 1.08 copy in 2 of 8 scenes, the 0.92 one in
    3; docs/measurements.md)."""
    from pcdet.synth import SynthConfig, synthesize

    folder = _with_copies(tmp_path)
    for f in folder.glob("obj_*.ply"):
        if f.stem not in ("obj_000001", "obj_000101", "obj_000201"):
            f.unlink()
    lib = ModelLibrary.from_folder(folder)
    m = lib[lib.index_of(201)]
    ds = BopDataset(synthesize(ModelLibrary([m]), tmp_path / "scenes", SynthConfig(scenes=8, objects=1, seed=7)))
    det = Detector(lib, PipelineConfig(), workers=1)
    assert [f.members for f in det.families] == [(0, 1, 2)] and det.families[0].representative == 0
    for img in ds:
        (gt,) = ds.gt(img)
        found = det.detect(ds.frame(img)).detections
        assert [d.obj_id for d in found] in ([1], [101], [201]), (img, found)
        assert adds(found[0].T_cam_model, gt["T_cam_model"], m.points) < 0.05 * m.diameter, (img, found)
    # the diagnosis counts the copy's matches through the bracket's candidate table
    img = ds.images[0]
    diag = diagnose_frame(det, ds.frame(img), ds.gt(img), None)[0]
    assert diag.keypoints_matched >= 3, diag


@pytest.mark.real
def test_on_real_frames_the_cat_is_kept_at_its_own_size(tmp_path):
    """Every 8th of the 40 real LINEMOD cat frames and the scanned cat at 0.92, 1 and 1.08 in the library, no
    targets: the cat is found within ADD 0.1 d in at least 4 of the 5 frames, and each cat kept is the true size,
    not a copy 8 % off (on frame 480 the verification score and the outline both prefer the 0.92 copy; the fitted
    scale, ``verify.size_margin``, decides)."""
    import json

    from pcdet.config import load_pipeline
    from pcdet.datasets import open_recording
    from pcdet.metrics import add

    data = shared("linemod_cat")
    info = json.loads((data / "models" / "models_info.json").read_text())
    mesh = trimesh.load(data / "models" / "obj_000006.ply", process=False)
    meta = {}
    for n, s in enumerate((1.0, 0.92, 1.08)):
        _scaled(mesh, s).export(tmp_path / f"obj_{6 + 100 * n:06d}.ply")
        meta[str(6 + 100 * n)] = {**info["6"], "diameter": info["6"]["diameter"] * s}
    (tmp_path / "models_info.json").write_text(json.dumps(meta))
    cfg = load_pipeline("default")
    det = Detector(ModelLibrary.from_folder(tmp_path, cfg), cfg)
    cat = det.models[det.library.index_of(6)].model
    rec = open_recording(data)
    found, kept = 0, {}
    for r in list(rec)[::8]:
        T = next(g["T_cam_model"] for g in rec.gt(r) if g["obj_id"] == 6)
        res = det.detect(rec.frame(r), None)
        kept[r.im_id] = [d.obj_id for d in res.detections]
        found += any(d.obj_id == 6 and add(d.T_cam_model, T, cat.points) < 0.1 * cat.diameter
                     for d in res.detections)
    assert found >= 4 and all(i == 6 for ids in kept.values() for i in ids), (found, kept)
