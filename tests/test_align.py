"""Kabsch and Umeyama: known transforms, reflections refused, TEASER++'s benchmark cases."""
import numpy as np
import pytest

from pcdet.align import kabsch, kabsch_batch, umeyama
from pcdet.metrics import rotation_error_deg

from .conftest import random_pose, shared


def test_kabsch_recovers_known_pose(rng):
    for _ in range(20):
        T = random_pose(rng)
        P = rng.normal(size=(30, 3)) * 0.1
        Q = P @ T[:3, :3].T + T[:3, 3] + rng.normal(0, 1e-4, P.shape)
        E = kabsch(P, Q)
        assert np.linalg.det(E[:3, :3]) == pytest.approx(1.0)
        assert rotation_error_deg(E[:3, :3], T[:3, :3]) < 0.1
        assert np.linalg.norm(E[:3, 3] - T[:3, 3]) < 1e-3


def test_kabsch_never_reflects(rng):
    P = rng.normal(size=(10, 3))
    E = kabsch(P, P * np.array([-1, 1, 1]))  # mirrored target: best proper rotation, det +1
    assert np.linalg.det(E[:3, :3]) == pytest.approx(1.0)


def test_weights_ignore_outliers(rng):
    T = random_pose(rng)
    P = rng.normal(size=(40, 3))
    Q = P @ T[:3, :3].T + T[:3, 3]
    Q[:10] += rng.normal(size=(10, 3))  # corrupted rows get zero weight
    w = np.r_[np.zeros(10), np.ones(30)]
    E = kabsch(P, Q, w)
    assert rotation_error_deg(E[:3, :3], T[:3, :3]) < 1e-4  # arccos near 1 resolves ~1e-6 degrees


def test_batch_agrees_with_scipy_align_vectors(rng):
    """kabsch_batch against an independent solver: scipy's Rotation.align_vectors on the centred, weighted
    points gives the same rotation, and t maps the weighted centroid onto the other's."""
    from scipy.spatial.transform import Rotation

    P = rng.normal(size=(5, 8, 3))
    Q = rng.normal(size=(5, 8, 3))
    W = rng.random((5, 8)) + 0.1
    B = kabsch_batch(P, Q, W)
    for i in range(5):
        cp = (W[i, :, None] * P[i]).sum(0) / W[i].sum()
        cq = (W[i, :, None] * Q[i]).sum(0) / W[i].sum()
        R, _ = Rotation.align_vectors(Q[i] - cq, P[i] - cp, weights=W[i])
        np.testing.assert_allclose(B[i, :3, :3], R.as_matrix(), atol=1e-9)
        np.testing.assert_allclose(B[i, :3, :3] @ cp + B[i, :3, 3], cq, atol=1e-12)


def _ply_points(path):
    from pcdet.io.clouds import read_cloud

    return read_cloud(path).points


@pytest.mark.parametrize("case", range(1, 7))
def test_teaser_cases_inliers(case):
    """Umeyama on the rows that the case's ground truth says are inliers recovers R, t, s."""
    d = shared("teaser_cases") / f"benchmark_{case}"
    src, dst = _ply_points(d / "src.ply"), _ply_points(d / "dst.ply")
    R = np.loadtxt(d / "R_ref.csv", delimiter=",")
    t = np.loadtxt(d / "t_ref.csv", delimiter=",").reshape(3)
    s = float(np.loadtxt(d / "s_ref.csv", delimiter=",").reshape(-1)[0])
    resid = np.linalg.norm(dst - (s * src @ R.T + t), axis=1)
    tol = 0.05 if case == 6 else 1e-3  # case 6 adds noise of sigma 0.01
    inl = resid < tol
    s_e, T_e = umeyama(src[inl], dst[inl])
    assert s_e == pytest.approx(s, rel=0.01)
    assert rotation_error_deg(T_e[:3, :3], R) < 1.0
    # t exact without noise (measured ~1e-15); with case 6's noise (sigma 0.01 on 10 points) 7.6e-3
    assert np.linalg.norm(T_e[:3, 3] - t) < (0.02 if case == 6 else 1e-9), T_e[:3, 3] - t


def test_kabsch_shared_equals_batch(rng):
    P, Q = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    W = rng.random((4, 50))
    from pcdet.align import kabsch_shared

    np.testing.assert_allclose(kabsch_shared(P, Q, W), kabsch_batch(np.broadcast_to(P, (4, 50, 3)),
                                                                     np.broadcast_to(Q, (4, 50, 3)), W), atol=1e-9)
