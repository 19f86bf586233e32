"""Keypoint selection: voxel spacing and ISS."""
import numpy as np

from pcdet.config import KeypointConfig
from pcdet.keypoints import select_keypoints


def test_voxel_keypoints_spacing(rng):
    pts = rng.uniform(0, 0.1, (4000, 3))
    kp = select_keypoints(pts, KeypointConfig(spacing=0.02))
    assert len(kp) == 125 and (np.diff(kp) > 0).all()  # one per occupied 2 cm cell, sorted indices


def test_iss_keypoints_find_every_corner_of_a_cube():
    """ISS on the even surface samples of a 10 cm cube (3 mm grid): each of the 8 corners has a keypoint within
    1 cm (measured: 4.7-7.0 mm), and ISS keeps a small minority of the samples (measured: 112 of 6534)."""
    import trimesh

    from pcdet.cloud import voxel_downsample

    pts, _ = trimesh.sample.sample_surface_even(trimesh.creation.box((0.1, 0.1, 0.1)), 30000, seed=1)
    pts, _, _ = voxel_downsample(np.asarray(pts), 0.003, representatives=False)
    kp = select_keypoints(pts, KeypointConfig(method="iss", iss_salient_radius=0.012, iss_non_max_radius=0.01))
    corners = np.array([[x, y, z] for x in (-0.05, 0.05) for y in (-0.05, 0.05) for z in (-0.05, 0.05)])
    nearest = np.linalg.norm(pts[kp][:, None] - corners[None], axis=2).min(axis=0)
    assert nearest.max() < 0.01, nearest
    assert 8 <= len(kp) < len(pts) / 20 and (np.diff(kp) > 0).all()


def test_keypoint_levels_are_each_spacings_own_grid(rng):
    """Keypoints chosen at three spacings at once (``voxel_keypoint_levels``): every level is exactly
    ``select_keypoints`` at its spacing (what a model with that grid groups when searched alone), ``kp`` is their
    sorted union, and each level's positions index it in ascending order."""
    from pcdet.keypoints import voxel_keypoint_levels

    pts = rng.uniform(0, 0.2, (20000, 3))
    steps = (0.01, 0.0137, 0.031)
    kp, levels = voxel_keypoint_levels(pts, steps)
    assert sorted(levels) == sorted(steps) and (np.diff(kp) > 0).all()
    for s, pos in levels.items():
        assert (np.diff(pos) > 0).all()
        np.testing.assert_array_equal(kp[pos], select_keypoints(pts, KeypointConfig(spacing=s)))
    assert len(kp) == len(set(np.concatenate([kp[p] for p in levels.values()]).tolist()))
    empty_kp, empty = voxel_keypoint_levels(np.zeros((0, 3)), [0.02])
    assert len(empty_kp) == 0 and len(empty[0.02]) == 0
