"""The hashed-grid nearest-point search (``pcdet.grid.GridTree``) must answer as the KD-tree it stands in for."""
import pickle

import numpy as np
import pytest
from scipy.spatial import cKDTree


def _surface(rng, n=20000):
    """Points on a few noisy planes and a sphere, 0-0.5 m, about as dense as a voxel-grid scene."""
    u = rng.uniform(0, 0.5, (n, 2))
    planes = np.c_[u, 0.1 + 0.002 * rng.normal(size=n)]
    walls = np.c_[0.3 + 0.002 * rng.normal(size=n // 2), u[: n // 2]]
    v = rng.normal(size=(n // 2, 3))
    ball = 0.25 + 0.08 * v / np.linalg.norm(v, axis=1, keepdims=True)
    return np.vstack([planes, walls, ball])


def test_grid_answers_as_the_kd_tree(rng):
    """Nearest index and distance within the bound, bit for bit, for queries on, near and far from the surface
    (radii 4, 7.5 and 12 mm, the overlap's and ICP's), with none within reach given as (inf, n); ``within`` is
    whether a point lies within reach. The grid is compiled by the project's set-up: a missing build fails."""
    from pcdet.grid import GridTree, compiled

    assert compiled(), "pcdet._grid was not built (is a C compiler installed?)"
    pts = _surface(rng)
    tree, grid = cKDTree(pts), GridTree(pts)
    q = np.vstack([pts[::7] + 0.004 * rng.normal(size=(len(pts[::7]), 3)), rng.uniform(-0.1, 0.6, (20000, 3))])
    for r in (0.004, 0.0075, 0.012):
        d0, j0 = tree.query(q, distance_upper_bound=r)
        d1, j1 = grid.query(q, distance_upper_bound=r)
        assert np.array_equal(d0, d1) and np.array_equal(j0, j1)
        hit = np.isfinite(d0)
        assert 0.1 < hit.mean() < 0.9 and (j1[~hit] == len(pts)).all()
        assert np.array_equal(grid.within(q, r), hit)


def test_within_any_is_the_kd_trees_answer_on_the_grid_and_without_it(rng, monkeypatch):
    """Whether any centre lies within r of each query, for model-like centres (a patch of the surface) and queries
    near and far: the KD-tree's answer, on the grid of the centres and with the kernel taken away; no centres or no
    queries give all False / an empty answer; centres too wide for the grid's keys at this radius fall back."""
    import pcdet.grid as grid

    pts = _surface(rng)
    centres = pts[(pts[:, 0] < 0.2) & (pts[:, 1] < 0.2)][::3]
    q = np.vstack([pts[::5], rng.uniform(-0.1, 0.6, (5000, 3))])
    for r in (0.006, np.nextafter(0.015, np.inf)):
        want = np.isfinite(cKDTree(centres).query(q, distance_upper_bound=r)[0])
        assert 0.02 < want.mean() < 0.9
        assert np.array_equal(grid.within_any(q, centres, r), want)
        with monkeypatch.context() as m:
            m.setattr(grid, "_grid", None)
            assert np.array_equal(grid.within_any(q, centres, r), want)
    assert not grid.within_any(q, centres[:0], 0.01).any() and len(grid.within_any(q[:0], centres, 0.01)) == 0
    wide = np.array([[0.0, 0.0, 0.0], [4e4, 0.0, 0.0]])  # 2^20 cells of 3 cm either side of 0 do not reach 40 km
    assert not grid.CellGrid(wide, 0.03 * (1 + 1e-9)).usable
    assert grid.within_any(np.array([[0.01, 0, 0], [0.05, 0, 0]]), wide, 0.03).tolist() == [True, False]


def test_grid_keeps_the_kd_tree_strict_bound_at_the_cell_faces(rng):
    """Points on a lattice of the cell's width, each moved by a multiple of 2^-12 m (so every sum below is exact),
    and queries the radius (0.25 m) away from some of them along an axis, on cell faces and corners: the same
    neighbours as the KD-tree's. A point exactly the radius away is outside (d < r, as for the KD-tree)."""
    from pcdet.grid import GridTree

    r = 0.25
    axis = np.arange(-4, 5) * r
    lattice = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    pts = lattice + rng.integers(0, 256, lattice.shape) * 2.0 ** -12
    q = np.vstack([pts[::3] + [r, 0, 0], pts[1::3] - [0, r, 0], lattice[::2], lattice[1::2] + [r / 2, 0, -r]])
    d0, j0 = cKDTree(pts).query(q, distance_upper_bound=r)
    d1, j1 = GridTree(pts).query(q, distance_upper_bound=r)
    assert np.array_equal(d0, d1) and np.array_equal(j0, j1)
    assert np.isfinite(d0).mean() > 0.3
    lone = GridTree(np.array([[0.0, 0.0, 0.0]]))
    assert lone.query(np.array([[0.25, 0, 0], [0.2499, 0, 0]]), distance_upper_bound=r)[1].tolist() == [1, 0]


def test_grid_any_thread_count_and_every_other_query_is_the_kd_trees(rng):
    """Two workers give what one gives; k > 1, an unbounded search, a 2-D tree and a cloud too wide for the grid's
    keys at this radius are answered by the KD-tree itself; asked at ten radii, the tree keeps the last eight grids
    (odometry asks at a radius of each frame's own); a pickled tree answers the same."""
    from pcdet.grid import GridTree

    pts = _surface(rng)
    grid = GridTree(pts)
    q = pts[:30000] + 0.003 * rng.normal(size=(30000, 3))
    one = grid.query(q, distance_upper_bound=0.01)
    two = grid.query(q, distance_upper_bound=0.01, workers=2)
    assert all(np.array_equal(a, b) for a, b in zip(one, two))
    tree = cKDTree(pts)
    for kw in (dict(k=3, distance_upper_bound=0.01), dict(), dict(eps=0.5, distance_upper_bound=0.01)):
        assert all(np.array_equal(a, b) for a, b in zip(tree.query(q[:500], **kw), grid.query(q[:500], **kw)))
    flat = rng.uniform(0, 1, (500, 2))
    assert all(np.array_equal(a, b) for a, b in zip(cKDTree(flat).query(flat + 0.01, distance_upper_bound=0.05),
                                                    GridTree(flat).query(flat + 0.01, distance_upper_bound=0.05)))
    wide = np.vstack([pts, [[5000.0, 0, 0]]])  # 5 km at 1 mm cells: beyond the packed keys
    assert all(np.array_equal(a, b) for a, b in zip(cKDTree(wide).query(q, distance_upper_bound=0.001),
                                                    GridTree(wide).query(q, distance_upper_bound=0.001)))
    for r in np.linspace(0.005, 0.02, 10):  # a radius per call, as odometry asks: only the last few grids are kept
        grid.query(q[:100], distance_upper_bound=r)
    assert len(grid._grids) == GridTree.KEEP
    again = pickle.loads(pickle.dumps(grid))
    assert isinstance(again, GridTree)
    assert all(np.array_equal(a, b) for a, b in zip(one, again.query(q, distance_upper_bound=0.01)))


def test_grid_kernel_refuses_arrays_that_do_not_make_a_grid():
    """The kernel reads raw memory: a start list that does not run from 0 to N, a table that is not a power of two,
    has no empty slot or names cells that do not exist, or a bound beyond the cell are refused with a ValueError,
    never read past (nor searched for ever)."""
    from pcdet import grid

    g = grid.CellGrid(np.array([[0.0, 0, 0], [0.5, 0, 0]]), 0.1)
    q, d2, j = np.zeros((1, 3)), np.empty(1), np.empty(1, np.int64)
    grid._grid.nearest(g.points, g.order, g.start, g.keys, g.table, 0.1, q, 0.01, d2, j, False)
    assert j[0] == 0 and d2[0] == 0
    for order, start, table, r2 in ((g.order, g.start + 1, g.table, 0.01), (g.order, g.start, g.table[:-1], 0.01),
                                    (g.order, g.start, g.table, 0.02), (g.order[:1], g.start, g.table, 0.01),
                                    (g.order, g.start, np.ones_like(g.table), 0.01),
                                    (g.order, g.start, np.full_like(g.table, 99), 0.01)):
        with pytest.raises(ValueError):
            grid._grid.nearest(g.points, order, start, g.keys, table, 0.1, q, r2, d2, j, False)


def test_detection_is_the_same_with_the_grid_and_with_the_kd_tree(synth_small, library, monkeypatch):
    """The detector's scene tree is a ``GridTree``: ICP and the overlap ranking search on its grids. On a synthetic
    frame the detections (model, score, pose, inliers) are those the KD-tree alone gives (the grid's queries
    switched off), to the bit. The grid stays on for the normals kernel, whose axes match open3d's only to
    rounding."""
    from pcdet import grid
    from pcdet.datasets.bop import BopDataset
    from pcdet.detector import Detector

    ds = BopDataset(synth_small)
    frame = ds.frame(ds.images[0])
    with_grid = Detector(library).detect(frame).detections
    monkeypatch.setattr(grid.GridTree, "_grid_for", lambda self, x, r: None)
    with_tree = Detector(library).detect(frame).detections
    assert len(with_grid) >= 2
    assert [d.to_dict() for d in with_grid] == [d.to_dict() for d in with_tree]


def test_components_link_what_query_pairs_links(rng):
    """``grid.components`` links the pairs that ``cKDTree.query_pairs`` returns, to the bit: pairs placed within
    a few units in the last place of the tolerance either way, and a noisy surface; each point gets the lowest index
    of its component. ``cloud.euclidean_clusters`` gives the same labels with it and without it."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from pcdet import cloud, grid

    r = 0.012
    a = rng.uniform(-0.3, 0.3, (3000, 3))
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    b = a + d * r * (1 + rng.integers(-3, 4, (3000, 1)) * 1.1e-16)
    for pts in (np.vstack([a, b]), _surface(rng, 6000)):
        pairs = cKDTree(pts).query_pairs(r, output_type="ndarray")
        n = len(pts)
        _, lab = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)))
        lowest = np.full(lab.max() + 1, n)
        np.minimum.at(lowest, lab, np.arange(n))
        assert np.array_equal(grid.components(pts, r), lowest[lab])
        with_kernel = cloud.euclidean_clusters(pts, r, 5)
        kernel, grid._grid = grid._grid, None
        try:
            assert np.array_equal(cloud.euclidean_clusters(pts, r, 5), with_kernel)
        finally:
            grid._grid = kernel
    # the boundary pairs matter: some within the tolerance by a unit in the last place are linked, some not
    linked = np.isin(np.arange(3000), cKDTree(np.vstack([a, b])).query_pairs(r, output_type="ndarray")[:, 0])
    assert 0.2 < linked.mean() < 0.9


def test_components_refuse_a_malformed_grid():
    from pcdet import _grid
    from pcdet.grid import CellGrid

    g = CellGrid(np.array([[0.0, 0, 0], [0.5, 0, 0]]), 0.1)
    with pytest.raises(ValueError):  # a radius beyond the cell
        _grid.clusters(g.points, g.order, g.start, g.keys, g.table, g.cell, 0.2 ** 2, np.empty(2, np.int64))
    with pytest.raises(ValueError):  # an index outside the cloud
        _grid.clusters(g.points, np.array([0, 5]), g.start, g.keys, g.table, g.cell, 0.01, np.empty(2, np.int64))
