"""Monocular 6-DoF pose from 2D-3D matches (PnP): OpenCV's EPnP inside its RANSAC, then Levenberg-Marquardt
refinement on the inliers. Needs OpenCV (``pip install 'pcdet[cv]'``)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from ..errors import DependencyError, InputError


@dataclass
class PnPResult:
    """``T_cam_model`` (4, 4, m); ``inliers`` (N,) bool; ``rmse_px`` reprojection error over the inliers."""

    T_cam_model: np.ndarray
    inliers: np.ndarray
    rmse_px: float


def solve_pnp(object_points, image_points, camera: Camera | np.ndarray, *, reprojection_error: float = 2.0,
              iterations: int = 1000, confidence: float = 0.999, seed: int = 0) -> PnPResult:
    """object_points : (N, 3) model points (m); image_points : (N, 2) their pixels (u, v); camera : a ``Camera``
    or a 3x3 K (no distortion). Needs N >= 4; ``ValueError`` when no pose has 4 inliers."""
    try:
        import cv2
    except ImportError:
        raise DependencyError("PnP needs OpenCV: pip install 'pcdet[cv]'") from None
    X = np.ascontiguousarray(object_points, np.float64)
    u = np.ascontiguousarray(image_points, np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or u.shape != (len(X), 2):
        raise InputError(f"need (N, 3) object points and (N, 2) image points, got {X.shape} and {u.shape}")
    if len(X) < 4:
        raise InputError(f"PnP needs at least 4 matches, got {len(X)}")
    K = camera.K if isinstance(camera, Camera) else np.asarray(camera, float).reshape(3, 3)
    cv2.setRNGSeed(seed)
    ok, rvec, tvec, inl = cv2.solvePnPRansac(X, u, K, None, iterationsCount=iterations,
                                             reprojectionError=reprojection_error, confidence=confidence,
                                             flags=cv2.SOLVEPNP_EPNP)
    if not ok or inl is None or len(inl) < 4:
        raise InputError(f"no pose with 4 or more matches within {reprojection_error} px")
    mask = np.zeros(len(X), bool)
    mask[inl.ravel()] = True
    rvec, tvec = cv2.solvePnPRefineLM(X[mask], u[mask], K, None, rvec, tvec)
    proj, _ = cv2.projectPoints(X, rvec, tvec, K, None)
    err = np.linalg.norm(proj.reshape(-1, 2) - u, axis=1)
    mask = err < reprojection_error
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.ravel()
    return PnPResult(T, mask, float(np.sqrt(np.mean(err[mask] ** 2))) if mask.any() else float("inf"))
