"""Voxel grid, plane segmentation and clustering: known answers, determinism."""
import numpy as np
import pytest

from pcdet.cloud import (
    estimate_normals,
    euclidean_clusters,
    orient_along_surface,
    outward_normals,
    segment_plane,
    voxel_downsample,
    voxel_keys,
)


def test_voxel_grid_means_and_representatives(rng):
    pts = rng.uniform(0, 0.1, (5000, 3))
    mean, _, rep = voxel_downsample(pts, 0.02)
    assert len(mean) == 125  # 5 x 5 x 5 cells, all occupied at this density
    keys = np.floor(pts / 0.02).astype(int)
    k0 = keys[rep]
    np.testing.assert_array_equal(np.floor(mean / 0.02).astype(int), k0)  # representative in its own cell
    m2, _, rep2 = voxel_downsample(pts[::-1].copy(), 0.02)
    np.testing.assert_allclose(m2, mean, atol=1e-12)  # order of input does not matter for the means


def test_voxel_keys_are_equal_exactly_within_one_cell(rng):
    """Two points share a key if and only if their floor(p / voxel) cells are equal: the same partition as a
    row-wise unique of the integer cells, with negative coordinates too."""
    pts = rng.uniform(-0.3, 0.2, (20000, 3))
    keys = voxel_keys(pts, 0.05)
    _, by_cell = np.unique(np.floor(pts / 0.05).astype(np.int64), axis=0, return_inverse=True)
    _, by_key = np.unique(keys, return_inverse=True)
    assert keys.dtype == np.int64 and keys.shape == (20000,)
    assert len(np.unique(by_cell)) == len(np.unique(by_key)) == 1000  # 10 x 10 x 10 cells, all occupied
    same_cell = by_cell.ravel()[:, None] == by_cell.ravel()[None, :200]
    same_key = by_key[:, None] == by_key[None, :200]
    np.testing.assert_array_equal(same_cell, same_key)


def test_plane_found_with_outliers(rng):
    n = np.array([0.1, -0.8, -0.3])
    n /= np.linalg.norm(n)
    u = np.cross(n, [1, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    P = rng.uniform(-0.5, 0.5, (3000, 2))
    plane_pts = np.array([0, 0, 1.0]) + P[:, :1] * u + P[:, 1:] * v + rng.normal(0, 0.002, (3000, 1)) * n
    clutter = rng.uniform([-0.3, -0.3, 0.5], [0.3, 0.3, 0.9], (1500, 3))
    pts = np.vstack([plane_pts, clutter])
    pl = segment_plane(pts, 0.008, 200, rng=0)
    assert abs(abs(pl.normal @ n) - 1) < 1e-3
    assert pl.normal @ np.array([0, 0, 1.0]) < 0  # faces the camera at the origin
    assert np.isin(np.arange(3000), pl.inliers).mean() > 0.99
    pl2 = segment_plane(pts, 0.008, 200, rng=0)
    np.testing.assert_array_equal(pl.inliers, pl2.inliers)  # seeded: identical


def test_clusters_separate_and_drop_small(rng):
    a = rng.normal([0, 0, 1], 0.01, (300, 3))
    b = rng.normal([0.3, 0, 1], 0.01, (200, 3))
    c = rng.normal([0, 0.3, 1], 0.002, (5, 3))
    lab = euclidean_clusters(np.vstack([a, b, c]), 0.02, min_size=10)
    assert set(lab[:300]) == {0} and set(lab[300:500]) == {1} and set(lab[500:]) == {-1}


@pytest.mark.parametrize("voxel", [0.005, 0.013])
def test_voxel_grid_normals_are_unit(rng, voxel):
    pts = rng.uniform(0, 0.1, (2000, 3))
    nrm = rng.normal(size=(2000, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    _, n, _ = voxel_downsample(pts, voxel, nrm)
    ok = np.linalg.norm(n, axis=1) > 0
    np.testing.assert_allclose(np.linalg.norm(n[ok], axis=1), 1, atol=1e-9)


def test_orientation_agrees_along_a_wavy_surface_split_in_two(rng):
    """A wavy sheet (z = 0.05 sin(20 x)) on a 1 cm grid, cut by a 5 cm gap that the 10-neighbour graph does not
    cross, with every normal's sign drawn at random: after ``orient_along_surface`` all normals agree with the
    true ones up to one global sign (the piece across the gap takes the sign of its nearest neighbour)."""
    x, y = np.meshgrid(np.arange(0, 0.6, 0.01), np.arange(0, 0.3, 0.01))
    x, y = x.ravel(), y.ravel()
    keep = (x < 0.28) | (x > 0.33)
    x, y = x[keep], y[keep]
    pts = np.stack([x, y, 0.05 * np.sin(20 * x)], axis=1)
    true = np.stack([-np.cos(20 * x), np.zeros_like(x), np.ones_like(x)], axis=1)
    true /= np.linalg.norm(true, axis=1, keepdims=True)
    flipped = true * rng.choice([-1.0, 1.0], len(true))[:, None]
    agree = (orient_along_surface(pts, flipped) * true).sum(axis=1)
    assert (agree > 0.99).all() or (agree < -0.99).all()


def test_outward_normals_point_away_from_the_centre_of_a_sphere(rng):
    """Normals estimated on a noisy unit-sphere sample (2000 points) all point outward (cosine > 0.9)."""
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = d * (1 + rng.normal(0, 0.002, (2000, 1)))
    n = outward_normals(pts, 0.15, 30)
    assert ((n * d).sum(axis=1) > 0.9).all()
    assert np.allclose(np.abs(estimate_normals(pts, 0.15, 30, viewpoint=None)), np.abs(n))


def test_diameter_is_the_largest_distance_between_two_points(rng):
    """Over the convex hull, exactly (to the last bit) the largest of all pairwise distances, which the test
    takes by brute force; a single point has diameter 0."""
    from pcdet.cloud import diameter

    for n, shape in ((500, (1.0, 0.3, 0.1)), (2000, (0.05, 0.05, 0.2))):
        P = rng.normal(size=(n, 3)) * shape
        brute = float(np.sqrt(((P[:, None, :] - P[None, :, :]) ** 2).sum(-1).max()))
        assert diameter(P) == brute
    assert diameter(np.ones((1, 3))) == 0.0
