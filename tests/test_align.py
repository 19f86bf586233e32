"""Kabsch and Umeyama: known transforms, reflections refused, TEASER++'s benchmark cases."""
import numpy as np
import pytest

from pcdet import align
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


@pytest.mark.real
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


@pytest.mark.real
def test_kabsch_shared_equals_batch(rng):
    P, Q = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    W = rng.random((4, 50))
    from pcdet.align import kabsch_shared

    np.testing.assert_allclose(kabsch_shared(P, Q, W), kabsch_batch(np.broadcast_to(P, (4, 50, 3)),
                                                                     np.broadcast_to(Q, (4, 50, 3)), W), atol=1e-9)


@pytest.mark.skipif(align._align is None, reason="the compiled kernel was not built")
def test_compiled_rotation_agrees_with_numpys_svd(rng):
    """The compiled kernel (Horn's quaternion) against numpy's SVD: rotation entries within 1e-12 on 500 random
    problems with noisy targets; on points in a plane or on a line (a repeated singular value) both fit exactly
    (residual under 1e-12 m) with det +1; on a mirrored target both reach the same trace(R H) within 1e-12 of
    each other, with det +1; a covariance holding NaN raises LinAlgError in both."""
    from scipy.spatial.transform import Rotation

    src = rng.normal(size=(500, 12, 3)) * rng.uniform(0.01, 1.0, (500, 1, 1))
    R = Rotation.random(500, random_state=1).as_matrix()
    dst = np.einsum("bij,bnj->bni", R, src) + rng.normal(size=(500, 1, 3)) + rng.normal(0, 0.01, src.shape)
    cs, cd = src.mean(1), dst.mean(1)
    H = np.einsum("bni,bnj->bij", src - cs[:, None], dst - cd[:, None])
    a = align._rigid_from_covariance(H, cs, cd)
    b = align._rigid_from_covariance(H, cs, cd, use_compiled=False)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    T = random_pose(rng)
    for P in (np.c_[rng.normal(size=(30, 2)), np.zeros(30)], np.outer(rng.normal(size=30), [1.0, 2.0, 3.0])):
        Q = P @ T[:3, :3].T + T[:3, 3]
        cs, cd = P.mean(0), Q.mean(0)
        H = ((P - cs).T @ (Q - cd))[None]
        for compiled in (True, False):
            E = align._rigid_from_covariance(H, cs[None], cd[None], use_compiled=compiled)[0]
            assert np.abs(P @ E[:3, :3].T + E[:3, 3] - Q).max() < 1e-12
            assert np.linalg.det(E[:3, :3]) == pytest.approx(1.0)
    P = rng.normal(size=(30, 3))
    Q = P * np.array([1.0, 1.0, -1.0])
    cs, cd = P.mean(0), Q.mean(0)
    H = ((P - cs).T @ (Q - cd))[None]
    Ea, Eb = (align._rigid_from_covariance(H, cs[None], cd[None], use_compiled=c)[0] for c in (True, False))
    assert np.linalg.det(Ea[:3, :3]) == pytest.approx(1.0)
    assert np.trace(Ea[:3, :3] @ H[0]) == pytest.approx(np.trace(Eb[:3, :3] @ H[0]), abs=1e-12)
    # a covariance holding NaN is refused by both, as numpy's SVD refuses it
    for compiled in (True, False):
        with pytest.raises(np.linalg.LinAlgError):
            align._rigid_from_covariance(np.full((1, 3, 3), np.nan), cs[None], cd[None], use_compiled=compiled)
