"""Keypoint selection: voxel spacing and ISS."""
import numpy as np

from pcdet.config import KeypointConfig
from pcdet.keypoints import select_keypoints


def test_voxel_keypoints_spacing(rng):
    pts = rng.uniform(0, 0.1, (4000, 3))
    kp = select_keypoints(pts, KeypointConfig(spacing=0.02))
    assert len(kp) == 125 and (np.diff(kp) > 0).all()  # one per occupied 2 cm cell, sorted indices


def test_iss_keypoints_on_a_box_corner_region(library):
    m = library[4]
    kp = select_keypoints(m.points, KeypointConfig(method="iss", iss_salient_radius=0.012, iss_non_max_radius=0.01))
    assert 5 < len(kp) < len(m.points) / 4  # ISS keeps a salient minority of the samples
