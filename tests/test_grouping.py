"""RANSAC grouping recovers a known pose from correspondences with many outliers, deterministically."""
import numpy as np
import pytest

from pcdet.config import GroupingConfig
from pcdet.grouping.pairs import pair_features, scene_pairs
from pcdet.grouping.ransac import ransac_instances
from pcdet.metrics import rotation_error_deg

from .conftest import random_pose


def _problem(model, rng, n=300, outlier_share=0.9, noise=0.001):
    """n scene keypoints on the posed model; a share of them matched to a random model keypoint."""
    K = len(model.kp_points)
    idx = rng.choice(K, n, replace=False)
    T = random_pose(rng, 0.2)
    T[2, 3] += 0.8
    S = model.kp_points[idx] @ T[:3, :3].T + T[:3, 3] + rng.normal(0, noise, (n, 3))
    N = model.kp_normals[idx] @ T[:3, :3].T
    cand = idx.copy()
    bad = rng.random(n) < outlier_share
    cand[bad] = rng.integers(0, K, bad.sum())
    return T, S, N, cand[:, None], bad


@pytest.mark.parametrize("outliers", [0.5, 0.9, 0.95])
def test_recovers_pose(library, rng, outliers):
    m = library[0]
    ok = 0
    for _ in range(10):
        T, S, N, cand, _ = _problem(m, rng, outlier_share=outliers)
        pairs = scene_pairs(S, N, np.zeros(len(S), int), m.diameter)
        hyps = ransac_instances(S, cand, m.kp_points, m.kp_normals, pairs, m.diameter, GroupingConfig(), rng)
        if hyps:
            E = hyps[0].T_cam_model
            ok += rotation_error_deg(E[:3, :3], T[:3, :3]) < 2 and np.linalg.norm(E[:3, 3] - T[:3, 3]) < 0.01
    assert ok >= 9, f"{ok}/10 trials within 2 degrees and 1 cm at {outliers:.0%} outliers"


def test_deterministic(library):
    m = library[1]
    T, S, N, cand, _ = _problem(m, np.random.default_rng(5))
    pairs = scene_pairs(S, N, np.zeros(len(S), int), m.diameter)
    a = ransac_instances(S, cand, m.kp_points, m.kp_normals, pairs, m.diameter, GroupingConfig(),
                         np.random.default_rng(3))
    b = ransac_instances(S, cand, m.kp_points, m.kp_normals, pairs, m.diameter, GroupingConfig(),
                         np.random.default_rng(3))
    assert len(a) == len(b) > 0
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.T_cam_model, y.T_cam_model)


def test_pair_features_are_rigid_invariant(rng):
    p1, p2 = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    n1, n2 = (v / np.linalg.norm(v, axis=1, keepdims=True) for v in rng.normal(size=(2, 50, 3)))
    T = random_pose(rng)
    R, t = T[:3, :3], T[:3, 3]
    f = pair_features(p1, n1, p2, n2)
    g = pair_features(p1 @ R.T + t, n1 @ R.T, p2 @ R.T + t, n2 @ R.T)
    np.testing.assert_allclose(f, g, atol=1e-4)


@pytest.mark.parametrize("outliers", [0.5, 0.9])
def test_consistency_grouping_recovers_pose(library, rng, outliers):
    from pcdet.grouping.consistency import consistency_groups

    m = library[0]
    ok = 0
    for _ in range(10):
        T, S, N, cand, bad = _problem(m, rng, outlier_share=outliers)
        dist = np.where(bad, 1.0, 0.5)[:, None] + rng.random((len(S), 1)) * 0.6  # descriptors rank imperfectly
        pairs = scene_pairs(S, N, np.zeros(len(S), int), m.diameter)
        hyps = consistency_groups(S, cand, dist, m.kp_points, m.kp_normals, pairs, m.diameter, GroupingConfig())
        if hyps:
            E = hyps[0].T_cam_model
            ok += rotation_error_deg(E[:3, :3], T[:3, :3]) < 2 and np.linalg.norm(E[:3, 3] - T[:3, 3]) < 0.01
    assert ok >= 9, f"{ok}/10 trials within 2 degrees and 1 cm at {outliers:.0%} outliers"


def test_detector_with_gc_grouping(synth_small, library):
    from pcdet.config import PipelineConfig
    from pcdet.datasets.bop import BopDataset
    from pcdet.detector import Detector
    from pcdet.metrics import add

    ds = BopDataset(synth_small)
    det = Detector(library, PipelineConfig().replace(grouping={"method": "gc"}))
    found = total = 0
    for img in ds:
        res = det.detect(ds.frame(img), ds.targets(img))
        for g in ds.gt(img):
            m = library.by_id(g["obj_id"])
            errs = [add(d.T_cam_model, g["T_cam_model"], m.points) for d in res.detections if d.obj_id == m.obj_id]
            found += bool(errs) and min(errs) < 0.1 * m.diameter
            total += 1
    assert found >= 0.7 * total, f"{found}/{total} within ADD 0.1 d"


def test_hough_votes_recover_pose(library, rng):
    """Correspondences carrying the model keypoints' own LRFs, rotated into the scene, 90 % outliers."""
    from pcdet.grouping.hough import hough_groups

    m = library[0]
    good = np.flatnonzero(~np.isnan(m.kp_lrfs[:, 0, 0]))
    ok = 0
    for _ in range(10):
        idx = rng.choice(good, 300, replace=False)
        T = random_pose(rng, 0.2)
        T[2, 3] += 0.8
        S = m.kp_points[idx] @ T[:3, :3].T + T[:3, 3] + rng.normal(0, 0.001, (300, 3))
        F = m.kp_lrfs[idx] @ T[:3, :3].T  # rows rotated into the scene
        cand = idx.copy()
        bad = rng.random(300) < 0.9
        cand[bad] = rng.choice(good, bad.sum())
        ref = m.points.mean(axis=0)
        hyps = hough_groups(S, F, cand[:, None], m.kp_points, m.kp_lrfs, ref, m.diameter, GroupingConfig())
        if hyps:
            E = hyps[0].T_cam_model
            ok += rotation_error_deg(E[:3, :3], T[:3, :3]) < 2 and np.linalg.norm(E[:3, 3] - T[:3, 3]) < 0.01
    assert ok >= 9, f"{ok}/10 trials within 2 degrees and 1 cm"
