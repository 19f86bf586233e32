"""pcdet.residuals: the correspondences within a radius of many poses, and one Tukey-weighted Kabsch step of each,
from the compiled kernel and from numpy alike."""
import numpy as np
import pytest

from pcdet import residuals
from pcdet.align import kabsch_batch, kabsch_from_sums

from .conftest import random_pose


def _scene(rng, extent: float, S: int = 3000, k: int = 4):
    """S scene keypoints in a cube of ``extent`` (m), k candidates each (consecutive rows, as the groupers lay them
    out), model points of a 6 cm blob, 40 poses; the first 400 correspondences are true for pose 5 (3 mm noise)."""
    model = rng.normal(0, 0.03, (400, 3))
    cs = np.repeat(rng.random((S, 3)) * extent, k, axis=0)
    cm = model[rng.integers(0, len(model), S * k)]
    T = np.stack([random_pose(rng) for _ in range(40)])
    T[:, :3, 3] = rng.random((40, 3)) * extent
    T[0] = np.eye(4)
    cs[:400] = cm[:400] @ T[5][:3, :3].T + T[5][:3, 3] + rng.normal(0, 0.003, (400, 3))
    return T, cm, cs


def test_the_compiled_kernel_is_built():
    assert residuals.compiled(), "pcdet._residuals was not built (is a C compiler installed?)"


@pytest.mark.parametrize("extent", [1.0, 0.1])
def test_within_equals_measuring_every_correspondence(rng, extent):
    """On a scene ten times the model's size (where both ways skip most correspondences by the ball test) and one
    the model's size (where numpy measures all): the sets, compiled and numpy, equal the brute-force
    ``pose_distances < r`` for every pose and radius. (A residual within a few units in the last place of r could
    fall either way between the two; none does here.)"""
    T, cm, cs = _scene(rng, extent)
    assert (residuals._in_reach(T, cm, cs, 0.01) is None) == (extent == 0.1)
    for r in (0.003, 0.01, 0.05):
        brute = [np.flatnonzero(row < r) for row in residuals.pose_distances(T, cm, cs)]
        for use in (True, False):
            got = residuals.within(T, cm, cs, r, use_compiled=use)
            assert len(got) == len(T)
            assert all(a.dtype == np.int64 and np.array_equal(a, b) for a, b in zip(got, brute))
    assert len(residuals.within(T, cm, cs, 0.01)[5]) >= 300


def test_within_of_no_pose_or_no_correspondence_is_empty(rng):
    T, cm, cs = _scene(rng, 0.1, S=200)
    assert residuals.within(T[:0], cm, cs, 0.01) == []
    got = residuals.within(T, cm[:0], cs[:0], 0.01)
    assert len(got) == len(T) and all(len(a) == 0 for a in got)


@pytest.mark.parametrize("c", [0.002, 0.01, 0.1])
def test_tukey_step_compiled_equals_numpy(rng, c):
    """The same poses that have 3 residuals under c, and the same steps within 1e-12 (m, and per rotation entry):
    the two sum the weights in different orders."""
    T, cm, cs = _scene(rng, 0.1)
    ok_c, T_c = residuals.tukey_step(T, cm, cs, c)
    ok_n, T_n = residuals.tukey_step(T, cm, cs, c, use_compiled=False)
    assert np.array_equal(ok_c, ok_n) and ok_c[5]
    np.testing.assert_allclose(T_c, T_n, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(T_c[~ok_c], T[~ok_c])  # a pose without 3 residuals under c stays


def test_tukey_step_pulls_a_pose_onto_its_true_correspondences(rng):
    """A pose 2 mm off the truth of 400 correspondences (3 mm noise) among 11,600 wrong ones: one step with a 1 cm
    kernel lands within 1 mm of it."""
    T, cm, cs = _scene(rng, 1.0)
    start = T[5:6].copy()
    start[0, :3, 3] += [0.002, 0, 0]
    ok, T1 = residuals.tukey_step(start, cm, cs, 0.01)
    assert ok[0] and np.linalg.norm(T1[0, :3, 3] - T[5, :3, 3]) < 0.001


def test_kernels_refuse_arrays_of_the_wrong_size():
    from pcdet import _residuals

    T, p = np.zeros((2, 4, 4)), np.zeros((5, 3))
    with pytest.raises(ValueError, match="within"):
        _residuals.within(T, p, np.zeros((4, 3)), 0.01)
    with pytest.raises(ValueError, match="within"):
        _residuals.within(np.zeros((2, 4, 3)), p, p, 0.01)
    with pytest.raises(ValueError, match="tukey_sums"):
        _residuals.tukey_sums(T, p, p, 0.01, np.zeros(1, np.int64), np.zeros((2, 16)))
    with pytest.raises(ValueError, match="tukey_sums"):
        _residuals.tukey_sums(T, p, p, 0.0, np.zeros(2, np.int64), np.zeros((2, 16)))


def test_kabsch_from_sums_equals_weighted_kabsch(rng):
    """The 16 weighted sums of each problem give the pose ``kabsch_batch`` gives with those weights, within 1e-12."""
    P = rng.normal(size=(4, 50, 3))
    Q = np.einsum("bij,bnj->bni", np.stack([random_pose(rng)[:3, :3] for _ in range(4)]), P) + 0.1
    W = rng.random((4, 50))
    sums = np.concatenate([W.sum(1)[:, None], np.einsum("bn,bni->bi", W, P), np.einsum("bn,bni->bi", W, Q),
                           np.einsum("bn,bni,bnj->bij", W, P, Q).reshape(4, 9)], axis=1)
    np.testing.assert_allclose(kabsch_from_sums(sums), kabsch_batch(P, Q, W), rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="zero"):
        kabsch_from_sums(np.zeros((1, 16)))
