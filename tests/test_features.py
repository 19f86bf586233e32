"""FPFH at keypoints: invariant to rigid motion, the same as Open3D's whole-cloud FPFH at those points, and
telling a corner from a flat patch; the compiled kernel against open3d where they must agree (to the bit) and where
they may not (neighbours at the same distance)."""
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


def _open3d_fpfh(pts, nrm, radius, max_nn):
    from pcdet._o3d import o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pc.normals = o3d.utility.Vector3dVector(nrm)
    f = o3d.pipelines.registration.compute_fpfh_feature(pc, o3d.geometry.KDTreeSearchParamHybrid(radius, max_nn))
    return np.asarray(f.data).T.astype(np.float32)


def test_the_kernel_is_compiled_and_gives_open3ds_descriptors(rng):
    """The compiled kernel (``pcdet/_fpfh.c``, built by the project's set-up: a missing build fails) gives open3d's
    descriptors to the bit on a cloud without two neighbours at the same distance (the only place where the two
    may differ: see the next test), with the support's neighbour limit reached (max_nn 30) and not (max_nn 100)."""
    from pcdet.features import compiled

    assert compiled(), "pcdet._fpfh was not built (is a C compiler installed?)"
    pts, nrm = _cube_samples()
    pts = pts + 1e-5 * rng.normal(size=pts.shape)  # no exact distance ties
    kp = np.arange(0, len(pts), 11)
    for max_nn in (30, 100):
        cfg = FeatureConfig(radius=0.02, max_nn=max_nn)
        ours = fpfh(pts, nrm, kp, cfg)
        assert np.array_equal(ours, _open3d_fpfh(pts, nrm, 0.02, max_nn)[kp])
        assert np.array_equal(ours, fpfh(pts, nrm, kp, cfg, kernel=False))


def test_neighbours_at_the_same_distance_are_taken_by_index():
    """On a lattice (many neighbours at the same distance to the bit) with more neighbours in reach than max_nn,
    which of the equally distant ones are kept is open3d's KD-tree's choice; the kernel keeps the lowest indices,
    so its descriptors do not depend on the order of the cloud beyond that rule, nor on the number of threads."""
    g = np.arange(-6, 7) * 0.004
    pts = np.stack(np.meshgrid(g, g, [0.0]), -1).reshape(-1, 3)
    pts[:, 2] = 0.3 * pts[:, 0] ** 2  # a curved sheet: the angles vary
    # normals tilted at random by up to ~3 degrees, so that neighbours at one distance (mirror images across the
    # sheet's symmetry) give other pair angles
    nrm = estimate_normals(pts, 0.012, 30, viewpoint=None) + np.random.default_rng(0).normal(0, 0.03, pts.shape)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    kp = np.arange(len(pts))
    # all in reach kept (max_nn 100): the same sets; equal distances summed in another order (float32 rounding)
    np.testing.assert_allclose(fpfh(pts, nrm, kp, FeatureConfig(radius=0.0165, max_nn=100)),
                               _open3d_fpfh(pts, nrm, 0.0165, 100), atol=1e-4)
    cfg = FeatureConfig(radius=0.0165, max_nn=40)  # up to 69 in reach: the 40th lies among ties
    one = fpfh(pts, nrm, kp, cfg, workers=1)
    assert np.array_equal(one, fpfh(pts, nrm, kp, cfg, workers=2))
    # the same cloud, reversed: every tie is broken the other way, the rest is the same
    rev = fpfh(pts[::-1].copy(), nrm[::-1].copy(), kp, cfg)[::-1]
    interior = (np.abs(pts[:, :2]) < 0.012).all(axis=1)
    assert (one[interior] != rev[interior]).any(axis=1).any()


def test_the_source_end_of_a_pair_is_chosen_as_open3d_chooses_it():
    """Three real scene points (LINEMOD cat frame, a flat patch) whose normals are (0, 0, -1) or one unit in the
    last place short of it: the cosines open3d compares differ in the last place, where its arc cosines would
    round to one value; open3d takes the end with the smaller |cos| as the source, and so does the kernel."""
    pts = np.array([[-0.9987522043973265, -0.7570217435447036, 1.9040000438690186],
                    [-0.9819258303534006, -0.7662542845047872, 1.8940000534057617],
                    [-0.9787945301385432, -0.7819184250717093, 1.9040000438690186]])
    nrm = np.array([[-1.2901414841418732e-10, -1.0342030306410931e-10, -1.0],
                    [0.0, -0.0, -0.9999999999999999],
                    [0.0, -0.0, -1.0]])
    cfg = FeatureConfig(radius=0.025, max_nn=100)
    assert np.array_equal(fpfh(pts, nrm, np.arange(3), cfg), _open3d_fpfh(pts, nrm, 0.025, 100))


def test_alpha_at_the_edges_of_its_bins_is_binned_as_open3d_bins_it():
    """The kernel approximates atan2 and asks atan2 itself near a bin's edge: two points whose pair angle alpha
    lies 1e-12 to 1e-3 rad either side of each edge reachable without swapping the ends get open3d's bins."""
    u = np.array([1.0, 0.0, 1.0]) / np.sqrt(2)  # the source's normal; the other end lies along x
    w = np.array([1.0, 0.0, -1.0]) / np.sqrt(2)  # u x v, with v = x x u normalised
    edges = -np.pi + 2 * np.pi * np.arange(1, 11) / 11
    cfg = FeatureConfig(radius=0.025, max_nn=100)
    tried = 0
    for edge in edges:
        for off in (1e-12, 1e-9, 1e-6, 1e-4, 3e-4, 1e-3):
            for theta in (edge - off, edge + off):
                n2 = np.cos(theta) * u + np.sin(theta) * w
                if abs(n2[0]) >= abs(u[0]):  # the ends would swap: alpha is another angle
                    continue
                pts = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0]])
                nrm = np.array([u, n2])
                tried += 1
                assert np.array_equal(fpfh(pts, nrm, np.arange(2), cfg), _open3d_fpfh(pts, nrm, 0.025, 100)), theta
    assert tried >= 50


def test_a_cloud_too_wide_for_the_grid_is_described_by_open3d(monkeypatch):
    """Points 100 km apart do not fit the grid's keys: open3d describes them (it is asked), and the result is its
    own."""
    from pcdet import features

    pts, nrm = _cube_samples()
    pts = np.vstack([pts, [[1e5, 0, 0]]])
    nrm = np.vstack([nrm, [[0, 0, 1.0]]])
    kp = np.arange(0, len(pts), 97)
    cfg = FeatureConfig(radius=0.02, max_nn=60)
    asked = []
    real = features._fpfh_open3d
    monkeypatch.setattr(features, "_fpfh_open3d", lambda *a: (asked.append(1), real(*a))[1])
    np.testing.assert_array_equal(fpfh(pts, nrm, kp, cfg), _open3d_fpfh(pts, nrm, 0.02, 60)[kp])
    assert asked == [1]
    fpfh(pts[:-1], nrm[:-1], kp[:-1], cfg)  # without the far point the kernel describes them
    assert asked == [1]


def test_the_kernel_refuses_malformed_arrays():
    """The kernel checks what it is given: indices outside the cloud, a histogram table without a neighbour's row,
    output of the wrong size are refused with a ValueError, not read out of bounds."""
    import pytest

    from pcdet import _fpfh
    from pcdet.grid import CellGrid

    pts, nrm = _cube_samples()
    g = CellGrid(pts, 0.02 * (1 + 1e-9))
    grid = (g.points, g.order, g.start, g.keys, g.table, g.cell)
    sorted_nrm = np.ascontiguousarray(nrm[g.order])
    with pytest.raises(ValueError):
        _fpfh.spfh(*grid, sorted_nrm, np.array([len(pts)]), 0.02 ** 2, 60, np.empty((1, 33)))
    with pytest.raises(ValueError):
        _fpfh.spfh(*grid, sorted_nrm, np.array([0]), 0.02 ** 2, 60, np.empty((2, 33)))
    with pytest.raises(ValueError):  # a radius beyond the cell
        _fpfh.reach(*grid, pts, np.array([0]), 0.03 ** 2, 60, np.zeros(len(pts), np.uint8))
    with pytest.raises(ValueError):  # no histogram for the neighbours
        _fpfh.fpfh(*grid, pts, np.array([0]), 0.02 ** 2, 60, np.zeros((1, 33)), np.full(len(pts), -1),
                   np.empty((1, 33)))
