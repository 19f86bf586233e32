"""2D transformations from point correspondences: affine (6 parameters, linear least squares) and homography
(normalised DLT with h33 = 1), each with a seeded RANSAC wrapper and a residual report.

Points are (N, 2) pixel coordinates; transforms are 3x3 matrices acting on homogeneous points, ``dst ~ H src``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError


def _pts(a, name) -> np.ndarray:
    a = np.asarray(a, float)
    if a.ndim != 2 or a.shape[1] != 2:
        raise InputError(f"{name} must be (N, 2), got shape {a.shape}")
    return a


def apply(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(N, 2) points mapped by the 3x3 ``H`` (with the perspective division)."""
    p = _pts(pts, "pts") @ H[:, :2].T + H[:, 2]
    return p[:, :2] / p[:, 2:3]


def fit_affine(src, dst) -> np.ndarray:
    """Least-squares affine map (3x3, last row 0 0 1) from >= 3 non-collinear correspondences: each gives two
    linear equations in the six unknowns a11 a12 tx a21 a22 ty."""
    src, dst = _pts(src, "src"), _pts(dst, "dst")
    if len(src) != len(dst) or len(src) < 3:
        raise InputError(f"an affine map needs >= 3 correspondences, got {len(src)} and {len(dst)}")
    A = np.zeros((2 * len(src), 6))
    A[0::2, 0:2], A[0::2, 2] = src, 1
    A[1::2, 3:5], A[1::2, 5] = src, 1
    if np.linalg.matrix_rank(A) < 6:
        raise InputError("the source points are collinear: the affine map is not determined")
    p = np.linalg.lstsq(A, dst.reshape(-1), rcond=None)[0]
    return np.array([[p[0], p[1], p[2]], [p[3], p[4], p[5]], [0.0, 0.0, 1.0]])


def _normaliser(p: np.ndarray) -> np.ndarray:
    """Hartley's normalisation: centroid to the origin, mean distance sqrt(2)."""
    c = p.mean(axis=0)
    d = np.mean(np.linalg.norm(p - c, axis=1))
    s = np.sqrt(2) / d if d > 0 else 1.0
    return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1]])


def fit_homography(src, dst) -> np.ndarray:
    """Homography (3x3, h33 = 1) from >= 4 correspondences by the normalised direct linear transform: both point
    sets normalised, the 2N x 9 system solved by SVD, the result denormalised and scaled to h33 = 1."""
    src, dst = _pts(src, "src"), _pts(dst, "dst")
    if len(src) != len(dst) or len(src) < 4:
        raise InputError(f"a homography needs >= 4 correspondences, got {len(src)} and {len(dst)}")
    Ts, Td = _normaliser(src), _normaliser(dst)
    s = src @ Ts[:2, :2].T + Ts[:2, 2]
    d = dst @ Td[:2, :2].T + Td[:2, 2]
    n = len(s)
    A = np.zeros((2 * n, 9))
    A[0::2, 0:2], A[0::2, 2] = s, 1
    A[0::2, 6:8], A[0::2, 8] = -d[:, :1] * s, -d[:, 0]
    A[1::2, 3:5], A[1::2, 5] = s, 1
    A[1::2, 6:8], A[1::2, 8] = -d[:, 1:] * s, -d[:, 1]
    _, sv, Vt = np.linalg.svd(A)
    if n >= 4 and sv[7] < 1e-10 * sv[0]:
        raise InputError("degenerate correspondences (three or more collinear): the homography is not determined")
    Hn = Vt[-1].reshape(3, 3)
    H = np.linalg.inv(Td) @ Hn @ Ts
    if abs(H[2, 2]) < 1e-12:
        raise InputError("h33 is zero: the homography maps the origin to infinity and cannot be scaled to h33 = 1")
    return H / H[2, 2]


@dataclass
class RansacResult:
    """``H`` (3x3) refitted on all inliers; ``inliers`` (N,) bool; ``residuals`` (N,) transfer error in pixels
    of every correspondence; ``rmse`` over the inliers; ``iterations`` drawn."""

    H: np.ndarray
    inliers: np.ndarray
    residuals: np.ndarray
    rmse: float
    iterations: int


def _ransac(fit, k: int, src, dst, threshold: float, *, iterations: int, seed: int, confidence: float
            ) -> RansacResult:
    src, dst = _pts(src, "src"), _pts(dst, "dst")
    n = len(src)
    if n < k or len(dst) != n:
        raise InputError(f"need >= {k} correspondences of equal count, got {n} and {len(dst)}")
    rng = np.random.default_rng(seed)
    best = np.zeros(n, bool)
    it, need = 0, iterations
    while it < min(need, iterations):
        it += 1
        idx = rng.choice(n, k, replace=False)
        try:
            H = fit(src[idx], dst[idx])
        except (ValueError, np.linalg.LinAlgError):
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.linalg.norm(apply(H, src) - dst, axis=1)
        inl = r < threshold
        if inl.sum() > best.sum():
            best = inl
            w = inl.mean()
            # adaptive stopping: draws needed to see one all-inlier sample with the given confidence
            need = int(np.ceil(np.log(1 - confidence) / np.log(max(1 - w ** k, 1e-12)))) if w < 1 else it
    if best.sum() < k:
        raise InputError(f"RANSAC found no model with {k} inliers within {threshold} px")
    for _ in range(3):  # refit on the inliers, then re-collect them
        H = fit(src[best], dst[best])
        r = np.linalg.norm(apply(H, src) - dst, axis=1)
        new = r < threshold
        if new.sum() < k or np.array_equal(new, best):
            break
        best = new
    return RansacResult(H, best, r, float(np.sqrt(np.mean(r[best] ** 2))), it)


def ransac_affine(src, dst, threshold: float = 2.0, iterations: int = 2000, seed: int = 0,
                  confidence: float = 0.999) -> RansacResult:
    """Affine map robust to outlier correspondences (3-point samples, inliers within ``threshold`` px)."""
    return _ransac(fit_affine, 3, src, dst, threshold, iterations=iterations, seed=seed, confidence=confidence)


def ransac_homography(src, dst, threshold: float = 2.0, iterations: int = 2000, seed: int = 0,
                      confidence: float = 0.999) -> RansacResult:
    """Homography robust to outlier correspondences (4-point samples, inliers within ``threshold`` px)."""
    return _ransac(fit_homography, 4, src, dst, threshold, iterations=iterations, seed=seed,
                   confidence=confidence)
