"""PnP on a models/ object projected by a known camera, with pixel noise and outlier matches."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pcdet.metrics import rotation_error_deg
from pcdet.synth import KINECT


def test_pose_from_noisy_matches_with_outliers(library, rng):
    """200 surface points of the bracket at 0.7 m, 0.5 px noise, 30 % of the matches replaced by random pixels:
    the pose comes back within 3 mm and 0.5 deg, and the outliers are flagged."""
    pytest.importorskip("cv2")
    from pcdet.image.pnp import solve_pnp

    m = library[0]
    X = m.points[rng.choice(len(m.points), 200, replace=False)]
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [20, -35, 60], degrees=True).as_matrix()
    T[:3, 3] = [0.03, -0.02, 0.7]
    Pc = X @ T[:3, :3].T + T[:3, 3]
    uv = KINECT.project(Pc) + rng.normal(0, 0.5, (200, 2))
    bad = rng.random(200) < 0.3
    uv[bad] = rng.uniform([0, 0], [640, 480], (bad.sum(), 2))
    r = solve_pnp(X, uv, KINECT)
    assert np.linalg.norm(r.T_cam_model[:3, 3] - T[:3, 3]) < 0.003
    assert rotation_error_deg(r.T_cam_model[:3, :3], T[:3, :3]) < 0.5
    assert (r.inliers == ~bad).mean() > 0.97 and r.rmse_px < 1.0


def test_too_few_matches():
    pytest.importorskip("cv2")
    from pcdet.image.pnp import solve_pnp

    with pytest.raises(ValueError, match="at least 4"):
        solve_pnp(np.zeros((3, 3)), np.zeros((3, 2)), KINECT)
