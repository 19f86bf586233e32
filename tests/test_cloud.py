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


def _noisy_surfaces(rng, n=6000):
    """(n, 3) m: a noisy wavy patch and a noisy sphere 0.3 m in front of the origin (no two points at one distance)."""
    xy = rng.uniform(-0.1, 0.1, (n // 2, 2))
    patch = np.c_[xy, 0.5 + 0.02 * np.sin(30 * xy[:, 0]) + rng.normal(0, 0.0005, n // 2)]
    d = rng.normal(size=(n - n // 2, 3))
    sphere = 0.05 * d / np.linalg.norm(d, axis=1, keepdims=True) + [0.2, 0.0, 0.4]
    return np.r_[patch, sphere]


@pytest.mark.slow
@pytest.mark.skipif(not __import__("pcdet.grid", fromlist=["compiled"]).compiled(), reason="kernel not built")
def test_compiled_normals_are_open3ds_up_to_rounding(rng):
    """On 6000 noisy surface points (radius 12 mm: 5-60 neighbours, so the cap of 30 applies to many), the compiled
    kernel's normals and open3d's span the same axis (1 - |cos| below 1e-12) and, turned toward the camera, have the
    same sign; with a cap larger than any neighbourhood too."""
    from pcdet import cloud

    assert cloud._normals is not None
    pts = _noisy_surfaces(rng)
    for max_nn in (30, 1000):
        ours = estimate_normals(pts, 0.012, max_nn)
        theirs = estimate_normals(pts, 0.012, max_nn, kernel=False)
        assert np.allclose(np.linalg.norm(ours, axis=1), 1.0, atol=1e-12)
        assert (1 - (ours * theirs).sum(axis=1)).max() < 1e-12


@pytest.mark.skipif(not __import__("pcdet.grid", fromlist=["compiled"]).compiled(), reason="kernel not built")
def test_compiled_normals_of_degenerate_neighbourhoods(rng):
    """A point with fewer than 3 neighbours, or whose neighbours lie at one place, gets (0, 0, 1), as open3d gives
    it (then turned toward the camera); neighbours along a line give a unit normal at right angles to it."""
    lone = np.array([[0.0, 0.0, 1.0], [0.5, 0.5, 1.0], [0.505, 0.5, 1.0]])
    same = np.repeat([[0.3, -0.2, 0.8]], 4, axis=0)
    line = np.c_[np.linspace(0, 0.02, 5), np.zeros(5), np.full(5, 0.9)] @ np.array(
        [[0.6, 0.8, 0.0], [-0.8, 0.6, 0.0], [0.0, 0.0, 1.0]])
    n = estimate_normals(np.r_[lone, same, line], 0.01, 30, viewpoint=None)
    assert np.array_equal(n[:7], np.tile([0.0, 0.0, 1.0], (7, 1)))
    assert np.allclose(np.linalg.norm(n[7:], axis=1), 1.0)
    assert np.abs(n[7:] @ np.array([0.6, 0.8, 0.0])).max() < 1e-9  # at right angles to the line's direction
    assert np.array_equal(estimate_normals(lone, 0.01, 30), np.tile([0.0, 0.0, -1.0], (3, 1)))


@pytest.mark.skipif(not __import__("pcdet.grid", fromlist=["compiled"]).compiled(), reason="kernel not built")
def test_compiled_normals_do_not_depend_on_how_the_points_are_split(rng):
    """The kernel's normals of any run of grid positions are those one call over all of them gives, to the bit (the
    detector splits them over its cores)."""
    from pcdet import _normals
    from pcdet.grid import CellGrid

    pts = _noisy_surfaces(rng, 3000)
    g = CellGrid(pts, 0.012 * (1 + 1e-9))
    grid = (g.points, g.order, g.start, g.keys, g.table, g.cell)
    whole = np.empty((len(pts), 3))
    _normals.normals(*grid, 0, len(pts), 0.012 ** 2, 30, whole)
    for cuts in ([0, 1, 1777, 3000], [0, 1500, 1500, 2999, 3000]):
        parts = np.empty_like(whole)
        for a, b in zip(cuts[:-1], cuts[1:]):
            _normals.normals(*grid, a, b, 0.012 ** 2, 30, parts[a:b])
        assert np.array_equal(parts, whole)
    with pytest.raises(ValueError, match="lo <= hi"):
        _normals.normals(*grid, 10, 5, 0.012 ** 2, 30, np.empty((0, 3)))


def test_normals_are_the_same_on_any_number_of_threads(rng):
    """``estimate_normals(..., workers=n)`` gives, to the bit, what one thread gives (above 4000 points the kernel
    splits the points over the threads)."""
    pts = _noisy_surfaces(rng, 6000)
    one = estimate_normals(pts, 0.012, 30, workers=1)
    for n in (2, 3, 0):
        assert np.array_equal(estimate_normals(pts, 0.012, 30, workers=n), one)
