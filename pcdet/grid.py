"""The nearest scene point within a short radius, on a hashed voxel grid: ``GridTree``.

ICP's correspondence search and the overlap ranking of pose hypotheses ask the scene's KD-tree one question, millions
of times a frame: the nearest point within a radius of about a centimetre (``cKDTree.query`` with
``distance_upper_bound``). For such a radius a grid of cells that wide answers it from the 27 cells around the
query, skipping those already farther than the best point found. ``GridTree`` is a ``cKDTree`` (every other query
is the KD-tree's) whose ``query`` takes that path for one neighbour (k=1, exact, Euclidean) within a finite bound,
with one grid per radius built on first use (the eight most recently used are kept). The answers are the
KD-tree's: the same index and the same distance, to the bit (``tests/test_grid.py``), except where several points
lie at the nearest distance to the bit: the grid takes the lowest index, the KD-tree one that its traversal meets
first. Real frames have such ties (16 of 970,000 odometry queries on the first 30 7-Scenes frames: depth in whole
millimetres on a pixel grid), so poses refined against a ``GridTree`` can differ from the KD-tree's in the last
digits (1e-7 m over the 300 frames).

The grid runs a compiled kernel (``pcdet/_grid.c``, built by ``setup.py`` where a C compiler is at hand); without
it every query is the KD-tree's. The same grid (``CellGrid``) links a cloud's points into Euclidean clusters
(``components``, the pairs ``cKDTree.query_pairs`` returns), finds FPFH's neighbours (``features.fpfh``) and tells
which scene points lie near a posed model (``within_any``, for global verification and RANSAC). On the
queries of two real 8-object frames (31,000-38,000 scene points), the
overlap ranking's 1.06 million (is a point within 7.5 mm?) took 0.23-0.26 s against the KD-tree's 0.42-0.43 s, and
ICP's 0.65 million (the nearest within 12 mm) 0.24-0.31 s against 0.53-0.60 s.
"""
from __future__ import annotations

import os
import threading
from collections import OrderedDict

import numpy as np
from scipy.spatial import cKDTree

try:  # the compiled kernel, where the install could build it
    from . import _grid
except ImportError:  # pragma: no cover - exercised where no compiler was at hand
    _grid = None

_REACH = 1 << 20  # cells per axis either side of 0 that a packed key holds


def over_threads(fn, items: np.ndarray, workers: int, min_items: int) -> list:
    """``[fn(part) for part in parts]``: ``items`` (an array) split along its first axis into one contiguous part per
    thread (``workers``; 0 or less: every core) and ``fn`` run on the parts at once, or ``[fn(items)]`` on one
    thread where there are fewer than ``min_items`` items. For the grid kernels, which release the interpreter lock and
    answer each item alone: the results, in order, are the same for any number of threads."""
    n = workers if workers > 0 else (os.cpu_count() or 1)
    parts = [p for p in np.array_split(items, n) if len(p)] if n > 1 and len(items) >= min_items else []
    if len(parts) < 2:
        return [fn(items)]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(len(parts)) as pool:
        return list(pool.map(fn, parts))


def over_ranges(fn, n: int, workers: int, min_items: int) -> None:
    """``fn(lo, hi)`` on contiguous ranges of ``0..n`` that cover it, one per thread (``over_threads``), for a kernel
    that writes its answers for positions lo..hi-1 into an array of its own."""
    over_threads(lambda part: fn(int(part[0]), int(part[-1]) + 1) if len(part) else None, np.arange(n), workers,
                 min_items)


def compiled() -> bool:
    """Whether the compiled kernel is in use (otherwise ``GridTree`` answers every query with its KD-tree)."""
    return _grid is not None


class CellGrid:
    """Points (N, 3) hashed into cubic cells of ``cell`` m (``pcdet/_grid.c`` describes the layout): ``points``
    (N, 3) float64 sorted by cell, ``order`` (N,) each one's index in the cloud as given, ``start``, ``keys`` and
    ``table``; ``usable`` False where the cloud is too wide for the packed keys (then nothing else is set)."""

    def __init__(self, points: np.ndarray, cell: float):
        self.cell = cell
        c = np.floor(points * (1.0 / cell))  # as the kernel computes a query's cell
        self.usable = bool(len(points) == 0 or np.abs(c).max() < _REACH)
        if not self.usable:  # a cloud too wide for the packed keys at this cell size: the KD-tree answers
            return
        c = c.astype(np.int64) + _REACH
        key = (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]
        self.order = np.argsort(key, kind="stable")
        key = key[self.order]
        self.points = np.ascontiguousarray(points[self.order], dtype=np.float64)
        self.keys, first = np.unique(key, return_index=True)
        self.start = np.r_[first, len(key)].astype(np.int64)
        size = 1 << max(4, int(np.ceil(np.log2(4 * max(len(self.keys), 1)))))  # at most a quarter full
        self.table = np.frombuffer(_grid.table(self.keys, size), np.int64)

    def nearest(self, queries: np.ndarray, r2: float, first: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(Q,) squared distance and index (into the points as given) of each query's nearest point with d2 < r2
        (the lowest index of several at that distance; inf and -1 where none); with ``first``, of the first point
        found within reach instead."""
        q = np.ascontiguousarray(queries, dtype=np.float64)
        d2, j = np.empty(len(q)), np.empty(len(q), np.int64)
        _grid.nearest(self.points, self.order, self.start, self.keys, self.table, self.cell, q, r2, d2, j, first)
        return d2, j


def components(points: np.ndarray, tolerance: float) -> np.ndarray | None:
    """(N,) int64: for each point (N, 3), the lowest index in its connected component, points linked where they lie
    at most ``tolerance`` m apart (as ``cKDTree.query_pairs`` decides it, to the bit); None where the kernel is not
    built, ``tolerance`` is not finite and positive, or the cloud is too wide for the grid's keys."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    if _grid is None or not 0 < tolerance < np.inf or points.ndim != 2 or points.shape[1] != 3:
        return None
    g = CellGrid(points, tolerance * (1 + 1e-9))  # a pair within tolerance lies in neighbouring cells
    if not g.usable:
        return None
    out = np.empty(len(points), np.int64)
    _grid.clusters(g.points, g.order, g.start, g.keys, g.table, g.cell, tolerance * tolerance, out)
    return out


def within_any(queries: np.ndarray, centres: np.ndarray, r: float) -> np.ndarray:
    """(Q,) bool: whether any of the (C, 3) ``centres`` lies within ``r`` m (d < r) of each (Q, 3) query, as
    ``cKDTree(centres).query(queries, distance_upper_bound=r)`` decides it; on a grid of the centres built for this
    one question (the KD-tree where the kernel is not built or the centres are too wide for the grid's keys), for the
    queries in the centres' box alone."""
    queries = np.asarray(queries, dtype=np.float64)
    centres = np.ascontiguousarray(centres, dtype=np.float64)
    out = np.zeros(len(queries), bool)
    if len(centres) == 0 or len(queries) == 0:
        return out
    # only the queries in the centres' box grown by r can have one within r (a whole frame asked about one object);
    # grown a hair more, so that rounding in the box's bounds drops none the exact test would keep
    lo, hi = centres.min(axis=0) - r * (1 + 1e-9), centres.max(axis=0) + r * (1 + 1e-9)
    box = np.flatnonzero((queries[:, 0] >= lo[0]) & (queries[:, 0] <= hi[0]) & (queries[:, 1] >= lo[1])
                         & (queries[:, 1] <= hi[1]) & (queries[:, 2] >= lo[2]) & (queries[:, 2] <= hi[2]))
    q = np.ascontiguousarray(queries[box])
    if _grid is not None and 0 < r < np.inf:
        g = CellGrid(centres, r * (1 + 1e-9))  # a centre within r lies in the 27 cells around the query's
        if g.usable:
            out[box] = g.nearest(q, r * r, first=True)[1] >= 0
            return out
    out[box] = np.isfinite(cKDTree(centres).query(q, distance_upper_bound=r)[0])
    return out


class GridTree(cKDTree):
    """A ``cKDTree`` (same constructor) whose nearest-neighbour queries within a finite ``distance_upper_bound``
    run on a hashed grid of that radius (module docstring): ``query(x, distance_upper_bound=r)`` for (Q, 3) ``x``
    returns what ``cKDTree.query`` returns, (Q,) distances (inf where none is within r) and indices (``n`` there).
    """

    KEEP = 8  # grids kept, the most recently used (detection asks at 4 radii a frame, odometry at a radius a frame)

    def __init__(self, data, *args, **kwargs):
        super().__init__(data, *args, **kwargs)
        self._grids: OrderedDict[float, CellGrid] = OrderedDict()
        self._lock = threading.Lock()

    def __reduce__(self):  # pickled as the points it was built on; the grids are built again on use
        return (GridTree, (np.asarray(self.data),))

    def _grid(self, r: float) -> CellGrid | None:
        with self._lock:
            g = self._grids.get(r)
            if g is None:  # cells a hair wider than r: a point within r lies in the 27 cells around the query's
                g = self._grids[r] = CellGrid(np.asarray(self.data), r * (1 + 1e-9))
                while len(self._grids) > self.KEEP:
                    self._grids.popitem(last=False)
            self._grids.move_to_end(r)
        return g if g.usable else None

    def _grid_for(self, x: np.ndarray, r: float) -> CellGrid | None:
        """The grid that answers queries ``x`` within ``r``, or None where the KD-tree must: no kernel, a bound
        that is not finite and positive, queries or points that are not 3-D, or a cloud too wide for the keys."""
        if _grid is None or not 0 < r < np.inf or x.ndim != 2 or x.shape[1] != 3 or self.m != 3:
            return None
        return self._grid(r)

    def query(self, x, k=1, eps=0, p=2, distance_upper_bound=np.inf, workers=1):
        """``cKDTree.query``; on the grid where k is 1, eps 0, p 2, the bound finite and positive and ``x`` (Q, 3)
        (``workers`` threads split the queries; each is answered alone, so any number gives the same)."""
        x = np.asarray(x)
        r = float(distance_upper_bound)
        g = self._grid_for(x, r) if k == 1 and eps == 0 and p == 2 else None
        if g is None:
            return super().query(x, k=k, eps=eps, p=p, distance_upper_bound=distance_upper_bound, workers=workers)
        r2 = r ** 2
        # the queries (Q, 3) split by rows; workers -1: every core, as for cKDTree
        found = over_threads(lambda part: g.nearest(part, r2), x, workers, 20000)
        d2, j = found[0] if len(found) == 1 else (np.concatenate([f[0] for f in found]),
                                                  np.concatenate([f[1] for f in found]))
        return np.sqrt(d2), np.where(j >= 0, j, self.n)

    def within(self, x: np.ndarray, r: float) -> np.ndarray:
        """(Q,) bool: whether a point lies within ``r`` (d < r) of each query (Q, 3); the grid stops at the first it
        finds."""
        x, r = np.asarray(x, dtype=np.float64), float(r)
        g = self._grid_for(x, r)
        if g is None:
            return np.isfinite(super().query(x, distance_upper_bound=r)[0])
        return g.nearest(x, r ** 2, first=True)[1] >= 0
