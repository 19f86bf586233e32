"""Metric definitions on cases with known values."""
import numpy as np
import pytest

from pcdet import metrics

from .conftest import random_pose


def test_add_zero_and_translation(rng):
    X = rng.normal(size=(500, 3)) * 0.05
    T = random_pose(rng)
    assert metrics.add(T, T, X) == pytest.approx(0.0)
    T2 = T.copy()
    T2[:3, 3] += [0.003, 0.004, 0]
    assert metrics.add(T2, T, X) == pytest.approx(0.005)
    assert metrics.mssd(T2, T, X) == pytest.approx(0.005)


def test_adds_forgives_symmetry():
    # a ring of points: rotating it about its axis changes ADD, not ADD-S
    a = np.linspace(0, 2 * np.pi, 360, endpoint=False)
    X = np.stack([0.05 * np.cos(a), 0.05 * np.sin(a), np.zeros_like(a)], axis=1)
    R = np.eye(4)
    c, s = np.cos(np.pi / 3), np.sin(np.pi / 3)
    R[:2, :2] = [[c, -s], [s, c]]
    assert metrics.add(R, np.eye(4), X) == pytest.approx(0.05, rel=1e-6)  # chord of 60 degrees = radius
    assert metrics.adds(R, np.eye(4), X) < 1e-9
    # a discrete symmetry given to MSSD removes the error
    assert metrics.mssd(R, np.eye(4), X, [R]) == pytest.approx(0.0, abs=1e-12)


def test_mspd_pixels():
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    X = np.array([[0.0, 0, 0], [0.01, 0, 0]])
    T = np.eye(4)
    T[2, 3] = 1.0
    T2 = T.copy()
    T2[0, 3] += 0.002  # 2 mm at 1 m = 1 px
    assert metrics.mspd(T2, T, X, K) == pytest.approx(1.0)


def test_matching_and_summary():
    X = np.random.default_rng(0).normal(size=(200, 3)) * 0.05
    T = np.eye(4)
    T[2, 3] = 1
    far = T.copy()
    far[0, 3] += 1.0
    gts = [{"obj_id": 1, "T_cam_model": T, "visib_fract": 1.0}]
    ests = [{"obj_id": 1, "score": 0.9, "T_cam_model": T}, {"obj_id": 1, "score": 0.5, "T_cam_model": far},
            {"obj_id": 2, "score": 0.4, "T_cam_model": T}]
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    errs, fp = metrics.match_image(gts, ests, {1: X}, K)
    assert len(errs) == 1 and errs[0].add == pytest.approx(0.0) and fp == 2
    s = metrics.summarize(errs, {1: 0.2}, fp)
    assert s["recall_add"] == 1.0 and s["precision_adds"] == pytest.approx(1 / 3) and s["ar"] == 1.0


def test_vsd_known_cases():
    d_gt = np.zeros((10, 10))
    d_gt[2:6, 2:6] = 1.0  # 16 px
    test = np.full((10, 10), 2.0)
    test[2:6, 2:6] = 1.0
    # identical estimate: no error at any tolerance
    np.testing.assert_allclose(metrics.vsd(d_gt, d_gt, test, [0.01, 0.05]), 0.0)
    # shifted by two columns: union 24 px, 8 px in both -> 16 / 24 wrong at any tau
    d_est = np.zeros((10, 10))
    d_est[2:6, 4:8] = 1.0
    assert metrics.vsd(d_est, d_gt, test, [0.05])[0] == pytest.approx(16 / 24)
    # same silhouette, 3 cm deeper: hidden behind the measured surface, but the GT-visible pixels it covers
    # count (BOP'19), so all 16 pixels are compared: wrong at tau = 1 cm, right at tau = 5 cm
    e = metrics.vsd(np.where(d_gt > 0, d_gt + 0.03, 0), d_gt, test, [0.01, 0.05])
    assert e[0] == pytest.approx(1.0) and e[1] == pytest.approx(0.0)


def test_average_recall_at_a_known_error():
    """One instance, estimate shifted 0.12 d sideways at 1 m depth (model points on the plane z = 0): MSSD is
    0.12 d, below 8 of the 10 thresholds 0.05..0.5 d; the shift is 6 px (f = 500, d = 0.1 m), below 9 of the 10
    thresholds 5..50 px. So AR_MSSD 0.8, AR_MSPD 0.9, AR 0.85 (no VSD), and ADD 0.12 d misses recall_add."""
    rng = np.random.default_rng(3)
    X = np.c_[rng.uniform(-0.04, 0.04, (300, 2)), np.zeros(300)]
    T = np.eye(4)
    T[2, 3] = 1.0
    est = T.copy()
    est[0, 3] += 0.012
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    errs, fp = metrics.match_image([{"obj_id": 1, "T_cam_model": T, "visib_fract": 1.0}],
                                   [{"obj_id": 1, "score": 1.0, "T_cam_model": est}], {1: X}, K,
                                   diameters={1: 0.1})
    assert fp == 0 and errs[0].mssd == pytest.approx(0.012) and errs[0].mspd == pytest.approx(6.0)
    s = metrics.summarize(errs, {1: 0.1}, fp)
    assert s["ar_mssd"] == pytest.approx(0.8) and s["ar_mspd"] == pytest.approx(0.9)
    assert s["ar"] == pytest.approx(0.85) and s["recall_add"] == 0.0 and "ar_vsd" not in s
