"""Synthetic scenes: noise model, ground truth consistent with the depth, determinism, BOP layout."""
import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pcdet.datasets.bop import BopDataset
from pcdet.sensor import apply_kinect_noise, kinect_sigma
from pcdet.synth import SynthConfig, synthesize


def test_noise_model(rng):
    assert kinect_sigma(np.array(0.4)) == pytest.approx(0.0012)
    assert kinect_sigma(np.array(1.4)) == pytest.approx(0.0031)
    depth = np.full((200, 200), 1.4, np.float32)
    raw = apply_kinect_noise(depth, rng)
    err = raw.astype(float) / 1000 - 1.4
    assert err.std() == pytest.approx(0.0031, rel=0.1)  # axial sigma plus 1 mm quantisation
    assert raw.dtype == np.uint16
    # raw units are millimetres, rounded without bias: 40 000 samples of 1400.3 mm average to it within 0.1 mm
    # (standard error 0.016 mm), and the noise spreads them over many 1 mm levels
    raw = apply_kinect_noise(np.full((200, 200), 1.4003, np.float32), rng)
    assert raw.astype(float).mean() == pytest.approx(1400.3, abs=0.1) and len(np.unique(raw)) > 10


def test_structured_light_noise_is_correlated_and_comes_in_disparity_steps(rng):
    """The structured-light model on a flat 1 m wall: RMS error within 15 % of the axial sigma (1.9 mm; the
    disparity steps add to it); neighbouring pixels' errors correlate (> 0.5 at one pixel, as on real Kinect
    frames, against < 0.05 for the independent model); depth falls on the steps of a 1/8-pixel disparity (at
    1 m, 572 px and 7.5 cm: 2.3 mm apart), so far fewer distinct values than millimetres in the spread."""
    from pcdet.sensor import structured_light

    depth = np.full((240, 320), 1.0)
    err = structured_light(depth, rng, fx=572.0).astype(float) / 1000 - 1.0
    assert err.std() == pytest.approx(float(kinect_sigma(np.array(1.0))), rel=0.15)

    def lag1(e):
        e = e - e.mean()
        return float((e[:, 1:] * e[:, :-1]).mean() / (e * e).mean())

    assert lag1(err) > 0.5
    assert abs(lag1(apply_kinect_noise(depth, rng).astype(float) / 1000 - 1.0)) < 0.05
    levels = np.unique(np.round(err * 1000))
    assert len(levels) < 0.6 * (levels.max() - levels.min() + 1)


def test_band_model_sees_past_foreground_edges_and_drops_nothing(rng):
    """structured_light_band on a step (a wall at 0.8 m on the left, 1.2 m on the right, 2000 rows): the near
    wall's pixels 1, 2 and 3 columns from the step report the far depth in the shares ``EDGE_BAND`` (within 0.04;
    binomial standard errors about 0.011), its pixels 4 or more columns in and the whole far wall never do, and
    no pixel is dropped (where ``structured_light`` drops pixels at the step)."""
    from pcdet.sensor import EDGE_BAND, apply_sensor

    depth = np.full((2000, 40), 1.2)
    depth[:, :20] = 0.8
    raw = apply_sensor("structured_light_band", depth, rng).astype(float) / 1000
    far = raw > 1.0  # noise is a few mm: a pixel is plainly near or far
    for n, share in enumerate(EDGE_BAND, start=1):
        assert far[:, 20 - n].mean() == pytest.approx(share, abs=0.04)
    assert not far[:, :20 - len(EDGE_BAND)].any() and far[:, 20:].all()
    assert (raw > 0).all()
    assert (apply_sensor("structured_light", depth, rng) == 0)[:, 19:21].mean() > 0.3


def test_perturbed_mesh_moves_the_surface_smoothly_by_the_rms_asked():
    """A 10 x 6 x 4 cm box bent with 1.2 mm RMS over 13 mm: the same faces as the unbent copy (subdivided to edges
    of 6.5 mm or less, so that the box can bend at all), vertices moved by 1.2 mm RMS (to 1e-9 m), and smoothly:
    the moves of vertices under 3 mm apart correlate above 0.9, those more than 6 cm apart below 0.3 in size."""
    import trimesh

    from pcdet.synth import perturbed_mesh

    box = trimesh.creation.box((0.1, 0.06, 0.04))
    v0, f0 = perturbed_mesh(box.vertices, box.faces, 0.0, 0.013, np.random.default_rng(0))
    v1, f1 = perturbed_mesh(box.vertices, box.faces, 0.0012, 0.013, np.random.default_rng(0))
    assert len(f0) > 100 * len(box.faces) and np.array_equal(f0, f1)
    edges = np.linalg.norm(v0[f0[:, [1, 2, 0]]] - v0[f0], axis=2)
    assert edges.max() <= 0.0065 + 1e-9
    d = v1 - v0
    assert np.sqrt(np.mean(np.sum(d * d, axis=1))) == pytest.approx(0.0012, abs=1e-9)
    normals = trimesh.Trimesh(v0, f0, process=False).vertex_normals
    m = np.sum(d * normals, axis=1)  # the signed move along the normal
    pairs = cKDTree(v0).query_pairs(0.003, output_type="ndarray")
    assert np.corrcoef(m[pairs[:, 0]], m[pairs[:, 1]])[0, 1] > 0.9
    rng = np.random.default_rng(1)
    a, b = rng.integers(0, len(v0), (2, 20000))
    far = np.linalg.norm(v0[a] - v0[b], axis=1) > 0.06
    assert abs(np.corrcoef(m[a[far]], m[b[far]])[0, 1]) < 0.3


def test_synth_mesh_error_bends_the_objects_not_the_scenes_or_models(tmp_path, library):
    """--mesh-error: the same poses and the same models/ as without it, but the objects' depth differs (by about
    the RMS asked: 1 to 4 mm median where both have depth on an object; the sensor model off, so only the
    meshes differ), and the table's depth not at all."""
    outs = {}
    for err in (0.0, 0.002):
        cfg = SynthConfig(scenes=1, objects=2, seed=5, noise=False, mesh_error=err)
        outs[err] = synthesize(library, tmp_path / str(err), cfg)
    a, b = (BopDataset(outs[e]) for e in (0.0, 0.002))
    gt = [(outs[e] / "test" / "000001" / "scene_gt.json").read_text() for e in (0.0, 0.002)]
    assert gt[0] == gt[1]
    for p in sorted((outs[0.0] / "models").iterdir()):
        assert p.read_bytes() == (outs[0.002] / "models" / p.name).read_bytes()
    da, db = a.frame(a.images[0]).depth, b.frame(b.images[0]).depth
    both = (da > 0) & (db > 0)
    diff = np.abs(da - db)[both]
    moved = diff > 0
    assert 0.001 < np.median(diff[moved]) < 0.004
    assert moved.mean() < 0.5  # the table (most of the image) is untouched


def test_synth_scenes_do_not_depend_on_the_sensor_model(tmp_path, library):
    """The same seed gives the same objects and poses whichever sensor model renders them."""
    gts = []
    for sensor in ("structured_light", "structured_light_band", "independent"):
        out = synthesize(library, tmp_path / sensor, SynthConfig(scenes=2, objects=2, seed=3, sensor=sensor))
        gts.append([json.loads((p / "scene_gt.json").read_text()) for p in sorted((out / "test").iterdir())])
    assert gts[0] == gts[1] == gts[2]


def test_ground_truth_matches_depth(synth_small, library):
    ds = BopDataset(synth_small)
    assert len(ds) == 3 and ds.models_dir is not None
    for img in ds:
        f = ds.frame(img)
        pts, _ = f.points()
        tree = cKDTree(pts)
        for g in ds.gt(img):
            m = library.by_id(g["obj_id"])
            T = g["T_cam_model"]
            P = m.points @ T[:3, :3].T + T[:3, 3]
            front = (m.normals @ T[:3, :3].T * P).sum(1) < 0
            d, _ = tree.query(P[front])
            # visible-side samples lie on measured points (noise ~2 mm, 4 mm sampling); some are occluded
            assert np.median(d) < 0.004
            assert 0 < g["visib_fract"] <= 1
        info = json.loads((ds.scene_dir(img.scene_id) / "scene_gt_info.json").read_text())
        assert len(info["0"]) == len(ds.gt(img))


def test_same_seed_same_bytes(tmp_path, library):
    a = synthesize(library, tmp_path / "a", SynthConfig(scenes=1, objects=2, seed=3))
    b = synthesize(library, tmp_path / "b", SynthConfig(scenes=1, objects=2, seed=3))
    for rel in ("test/000001/depth/000000.png", "test/000001/scene_gt.json"):
        assert (a / rel).read_bytes() == (b / rel).read_bytes()


def test_distractors_are_rendered_without_ground_truth(tmp_path, library):
    """Distractors put surfaces in front of the table that no ground-truth object explains: rendering only the
    table and the ground-truth objects from the scene's camera leaves over 500 pixels that the depth image has
    more than 2 cm nearer; without distractors, none."""
    from pcdet.render import render_meshes
    from pcdet.synth import _table_mesh

    def unexplained(cfg, name):
        ds = BopDataset(synthesize(library, tmp_path / name, cfg))
        img = next(iter(ds))
        f = ds.frame(img)
        cam = json.loads((ds.scene_dir(img.scene_id) / "scene_camera.json").read_text())["0"]
        T_cw = np.eye(4)
        T_cw[:3, :3] = np.reshape(cam["cam_R_w2c"], (3, 3))
        T_cw[:3, 3] = np.array(cam["cam_t_w2c"]) / 1000
        meshes = [(*_table_mesh(), T_cw)] + [(library.by_id(g["obj_id"]).vertices,
                                              library.by_id(g["obj_id"]).faces, g["T_cam_model"])
                                             for g in ds.gt(img)]
        expected = render_meshes(f.camera, meshes).depth
        return int(((f.depth > 0) & ((expected == 0) | (f.depth < expected - 0.02))).sum())

    # the meshes exactly as the models (no mesh error), so that only distractors can be left unexplained
    assert unexplained(SynthConfig(scenes=1, objects=2, distractors=3, seed=5, noise=False, mesh_error=0), "a") > 500
    assert unexplained(SynthConfig(scenes=1, objects=2, seed=5, noise=False, mesh_error=0), "b") == 0


@pytest.mark.slow
def test_synth_lays_flat_models_on_their_face(tmp_path):
    """Models with no volume, which trimesh's stable-pose analysis cannot take (a one-triangle model made qhull
    raise; a zero-thickness square made it loop for ever), lie on the table on their face: `pcdet synth` finishes
    (within 120 s, in a subprocess) and, in each of 2 scenes, the square (10 cm, modelled standing in its x-z
    plane) shows over 2,000 pixels from the camera above the table (3,412 and 4,833 measured), where standing
    on its edge it would show next to none."""
    import subprocess
    import sys

    import trimesh

    models = tmp_path / "models"
    models.mkdir()
    trimesh.creation.icosphere(subdivisions=3, radius=0.04).export(models / "ball.ply")
    square = trimesh.creation.box((0.1, 0.1, 0.0))
    square.vertices = square.vertices[:, [0, 2, 1]]  # the square upright, in its x-z plane
    square.export(models / "square.ply")
    trimesh.Trimesh([[0, 0, 0], [0.08, 0, 0], [0, 0.08, 0]], [[0, 1, 2]]).export(models / "tri.ply")
    out = tmp_path / "syn"
    r = subprocess.run([sys.executable, "-m", "pcdet.cli", "synth", "--models", str(models), "--out", str(out),
                        "--scenes", "2", "--objects", "3", "--seed", "5"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    ids = {m["name"]: int(k) for k, m in json.loads((out / "models" / "models_info.json").read_text()).items()}
    for scene in ("000001", "000002"):
        gt = json.loads((out / "test" / scene / "scene_gt.json").read_text())["0"]
        info = json.loads((out / "test" / scene / "scene_gt_info.json").read_text())["0"]
        (px,) = [i["px_count_visib"] for g, i in zip(gt, info) if g["obj_id"] == ids["square"]]
        assert px > 2000, (scene, px)
