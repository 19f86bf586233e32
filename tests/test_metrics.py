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
    """One instance, a right estimate (score 0.9) and a far one (0.5): the right one is matched, the far one
    counts against precision; recall and AR are 1."""
    X = np.random.default_rng(0).normal(size=(200, 3)) * 0.05
    T = np.eye(4)
    T[2, 3] = 1
    far = T.copy()
    far[0, 3] += 1.0
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    o = metrics.object_errors([{"T_cam_model": T, "visib_fract": 1.0}],
                              [{"score": 0.9, "T_cam_model": T}, {"score": 0.5, "T_cam_model": far}], X, K, 0.2)
    assert o.errors["add"].shape == (2, 1) and o.errors["add"][0, 0] == pytest.approx(0.0)
    assert metrics.match(o.errors["add"], o.scores, 0.02) == [(0, 0)]
    s = metrics.summarize([o])
    assert s["recall_add"] == 1.0 and s["precision_adds"] == pytest.approx(1 / 2) and s["ar"] == 1.0


def test_matching_goes_by_score_then_by_error():
    """BOP's rule: the higher-scored estimate picks first, and takes its nearest instance even when a
    lower-scored estimate would have fitted that instance better."""
    err = np.array([[0.1, 0.2], [0.05, 0.9]])
    assert metrics.match(err, np.array([0.9, 0.8]), 0.5) == [(0, 0)]
    assert metrics.match(err, np.array([0.9, 0.8]), 1.0) == [(0, 0), (1, 1)]
    assert metrics.match(err, np.array([0.1, 0.8]), 1.0) == [(1, 0), (0, 1)]


def test_each_recall_is_matched_by_its_own_error():
    """An estimate that is right by ADD-S (a ring turned about its axis) but wrong by MSSD without symmetries:
    recall_adds counts it; with the ring's continuous symmetry, MSSD counts it too."""
    a = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    X = np.stack([0.05 * np.cos(a), 0.05 * np.sin(a), np.zeros_like(a)], axis=1)
    T = np.eye(4)
    T[2, 3] = 1.0
    turned = T.copy()
    c, s_ = np.cos(2.5), np.sin(2.5)  # points move up to 0.95 d: wrong at every MSSD threshold
    turned[:2, :2] = [[c, -s_], [s_, c]]
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    gts, ests = [{"T_cam_model": T, "visib_fract": 1.0}], [{"score": 1.0, "T_cam_model": turned}]
    plain = metrics.summarize([metrics.object_errors(gts, ests, X, K, 0.1)])
    assert plain["recall_adds"] == 1.0 and plain["recall_add"] == 0.0 and plain["ar_mssd"] == 0.0
    syms = metrics.symmetry_transforms({"symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]})
    assert len(syms) == int(np.ceil(np.pi / 0.01))
    sym = metrics.summarize([metrics.object_errors(gts, ests, X, K, 0.1, symmetries=syms)])
    assert sym["ar_mssd"] == 1.0 and sym["ar_mspd"] == 1.0


def test_discrete_symmetries_are_read_in_millimetres():
    """A box turned half a turn about z is exact by MSSD with its discrete symmetry (translation in mm)."""
    X = np.random.default_rng(1).uniform([-0.04, -0.02, -0.01], [0.04, 0.02, 0.01], (300, 3)) + [0, 0, 0.01]
    flip = np.diag([-1.0, -1.0, 1.0, 1.0])
    T = np.eye(4)
    T[2, 3] = 0.8
    syms = metrics.symmetry_transforms({"symmetries_discrete": [flip.reshape(-1).tolist()]})
    assert len(syms) == 2
    assert metrics.mssd(T @ flip, T, X) > 0.03 and metrics.mssd(T @ flip, T, X, syms) < 1e-9


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
    o = metrics.object_errors([{"T_cam_model": T, "visib_fract": 1.0}], [{"score": 1.0, "T_cam_model": est}], X, K,
                              0.1)
    assert o.errors["mssd"][0, 0] == pytest.approx(0.012) and o.errors["mspd"][0, 0] == pytest.approx(6.0)
    s = metrics.summarize([o])
    assert s["ar_mssd"] == pytest.approx(0.8) and s["ar_mspd"] == pytest.approx(0.9)
    assert s["ar"] == pytest.approx(0.85) and s["recall_add"] == 0.0 and "ar_vsd" not in s
