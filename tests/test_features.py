"""FPFH at keypoints: invariant to rigid motion, the same as Open3D's whole-cloud FPFH at those points, and
telling a corner from a flat patch."""
import numpy as np
import trimesh

from pcdet.cloud import estimate_normals, voxel_downsample
from pcdet.config import FeatureConfig
from pcdet.features import fpfh

from .conftest import random_pose


def _cube_samples():
    pts, _ = trimesh.sample.sample_surface_even(trimesh.creation.box((0.1, 0.1, 0.1)), 40000, seed=2)
    pts, _, _ = voxel_downsample(np.asarray(pts), 0.004, representatives=False)
    return pts, estimate_normals(pts, 0.012, 30, viewpoint=None)


def test_fpfh_is_invariant_to_a_rigid_motion(rng):
    """The same cloud moved by a random pose gives the same descriptors (float32 rounding only)."""
    pts, nrm = _cube_samples()
    kp = np.arange(0, len(pts), 37)
    cfg = FeatureConfig(radius=0.025, max_nn=100)
    a = fpfh(pts, nrm, kp, cfg)
    T = random_pose(rng)
    b = fpfh(pts @ T[:3, :3].T + T[:3, 3], nrm @ T[:3, :3].T, kp, cfg)
    assert a.shape == (len(kp), 33) and a.dtype == np.float32
    np.testing.assert_allclose(a, b, atol=0.05)  # histogram entries sum to 100 per sub-histogram


def test_fpfh_at_keypoints_equals_open3d_on_the_whole_cloud():
    """Describing only the keypoints (neighbours from the full cloud) gives what Open3D's legacy FPFH gives for
    those points when it describes every point."""
    from pcdet._o3d import o3d

    pts, nrm = _cube_samples()
    kp = np.arange(3, len(pts), 53)
    ours = fpfh(pts, nrm, kp, FeatureConfig(radius=0.02, max_nn=60))
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pc.normals = o3d.utility.Vector3dVector(nrm)
    ref = o3d.pipelines.registration.compute_fpfh_feature(pc, o3d.geometry.KDTreeSearchParamHybrid(0.02, 60))
    np.testing.assert_allclose(ours, np.asarray(ref.data).T[kp], atol=1e-4)  # float32 rounding only


def test_fpfh_rows_follow_the_keypoints_in_the_order_given():
    """Open3D returns the descriptors of the requested points in increasing index order; ``fpfh`` gives row i to
    ``keypoints[i]`` whatever the order, repeats included (exactly the rows of the sorted request)."""
    pts, nrm = _cube_samples()
    cfg = FeatureConfig(radius=0.02, max_nn=60)
    kp = np.arange(3, len(pts), 53)
    ref = fpfh(pts, nrm, kp, cfg)
    perm = np.random.default_rng(1).permutation(len(kp))
    np.testing.assert_array_equal(fpfh(pts, nrm, kp[perm], cfg), ref[perm])
    np.testing.assert_array_equal(fpfh(pts, nrm, kp[[4, 0, 4, 2]], cfg), ref[[4, 0, 4, 2]])


def test_fpfh_tells_a_corner_from_a_face():
    """Two keypoints at the middle of two faces describe alike; a corner keypoint differs from both by more
    than five times as much."""
    pts, nrm = _cube_samples()
    face_a = np.argmin(np.linalg.norm(pts - [0.05, 0, 0], axis=1))
    face_b = np.argmin(np.linalg.norm(pts - [0, 0.05, 0], axis=1))
    corner = np.argmin(np.linalg.norm(pts - [0.05, 0.05, 0.05], axis=1))
    f = fpfh(pts, nrm, np.array([face_a, face_b, corner]), FeatureConfig(radius=0.02, max_nn=100))
    same = np.linalg.norm(f[0] - f[1])
    assert np.linalg.norm(f[2] - f[0]) > 5 * same and np.linalg.norm(f[2] - f[1]) > 5 * same


def test_no_keypoints_gives_an_empty_table():
    pts, nrm = _cube_samples()
    assert fpfh(pts, nrm, np.zeros(0, np.int64), FeatureConfig()).shape == (0, 33)
