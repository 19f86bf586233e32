"""Affine and homography estimation: exact on clean points, and under 1 px corner error from noisy matches with
50 % outliers (RANSAC)."""
import numpy as np
import pytest

from pcdet.image import fit_affine, fit_homography, ransac_affine, ransac_homography
from pcdet.image.transforms import apply

CORNERS = np.array([[0, 0], [640, 0], [640, 480], [0, 480]], float)
H_TRUE = np.array([[0.9, 0.12, 30.0], [-0.08, 1.05, 12.0], [2e-4, -1e-4, 1.0]])
A_TRUE = np.array([[0.95, -0.2, 40.0], [0.15, 1.1, -25.0], [0.0, 0.0, 1.0]])


def _matches(T, rng, n=200, outliers=0.5, noise=0.5):
    src = rng.uniform([0, 0], [640, 480], (n, 2))
    dst = apply(T, src) + rng.normal(0, noise, (n, 2))
    bad = rng.random(n) < outliers
    dst[bad] = rng.uniform([0, 0], [640, 480], (bad.sum(), 2))
    return src, dst, bad


def test_exact_on_clean_points(rng):
    src = rng.uniform(0, 500, (6, 2))
    assert np.allclose(fit_homography(src, apply(H_TRUE, src)), H_TRUE, atol=1e-9)
    assert np.allclose(fit_affine(src, apply(A_TRUE, src)), A_TRUE, atol=1e-9)
    assert fit_homography(src, apply(H_TRUE, src))[2, 2] == 1.0


@pytest.mark.parametrize("kind", ["homography", "affine"])
def test_ransac_with_half_outliers_gets_the_corners_within_1px(kind, rng):
    T = H_TRUE if kind == "homography" else A_TRUE
    src, dst, bad = _matches(T, rng)
    res = (ransac_homography if kind == "homography" else ransac_affine)(src, dst, threshold=2.0, seed=1)
    err = np.linalg.norm(apply(res.H, CORNERS) - apply(T, CORNERS), axis=1)
    assert err.max() < 1.0, err
    assert (res.inliers == ~bad).mean() > 0.97
    assert res.rmse < 1.0 and len(res.residuals) == len(src)


def test_degenerate_input_is_refused():
    line = np.column_stack([np.arange(5.0), 2 * np.arange(5.0)])
    with pytest.raises(ValueError, match="collinear"):
        fit_affine(line, line)
    with pytest.raises(ValueError, match=">= 4"):
        fit_homography(line[:3], line[:3])
