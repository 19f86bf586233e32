"""Graph kernels of the correspondence groupers: the tests of candidate pairs that a compatibility graph is built
from (``compatible_pairs``, the length and the angle tests, compiled; ``length_matches``, the length test in numpy),
and the common neighbours of each edge of a sparse undirected graph in CSR form (``common_neighbours``; ``start``,
``deg``, ``nbr``: row i lists its neighbours ``nbr[start[i]:start[i] + deg[i]]``, ascending, and every edge appears
in both rows).

They run a small compiled kernel (``pcdet/_graph.c``, built by ``setup.py`` when pcdet is installed where a C
compiler is at hand) and otherwise numpy and scipy, with the same results (``grouping.common`` takes the numpy
tests where the kernel was not built). On the 16 compatibility graphs of two real 8-object frames
(44,000-832,000 entries) the common neighbours took 0.14 s against scipy's 1.28 s. The angle test cannot round its
arc cosines as numpy's float32 code does, so the kernel decides it only where that rounding cannot matter and hands
numpy the rest (on the 112 graphs of every 3rd real cat frame, 8 models given, it kept 13.8 million pairs and left
196 to numpy). Those 112 graphs took 3.8 s to build on one thread, against 6.7 s with the angle test in numpy, and
are the same graphs.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sparse

try:  # the compiled kernel, where the install could build it
    from . import _graph
except ImportError:  # pragma: no cover - exercised where no compiler was at hand
    _graph = None


def compiled() -> bool:
    """Whether the compiled kernels are in use (otherwise numpy and scipy compute the same results)."""
    return _graph is not None


def common_neighbours(start: np.ndarray, deg: np.ndarray, nbr: np.ndarray, *, use_compiled: bool = True
                      ) -> np.ndarray:
    """(E,) float64: for every entry e of ``nbr`` (an edge i -> j), the number of vertices adjacent to both i and j
    (the triangles through the edge). start, deg : (M,) int64; nbr : (E,) int64. ``use_compiled`` False takes
    scipy's ``A.multiply(A @ A)`` even where the kernel is built (the tests compare the two)."""
    start = np.ascontiguousarray(start, dtype=np.int64)
    deg = np.ascontiguousarray(deg, dtype=np.int64)
    nbr = np.ascontiguousarray(nbr, dtype=np.int64)
    indptr = np.r_[0, np.cumsum(deg)]
    if len(start) != len(deg) or not np.array_equal(start, indptr[:-1]) or indptr[-1] != len(nbr):
        raise ValueError("common_neighbours: the rows must follow one another in nbr (start = cumulative deg, "
                         f"{len(nbr)} entries in all), got {len(start)} starts for {len(deg)} rows")
    out = np.zeros(len(nbr))
    if use_compiled and _graph is not None:
        _graph.common_neighbours(start, deg, nbr, out)
        return out
    M = len(deg)
    A = sparse.csr_matrix((np.ones(len(nbr), np.float32), nbr, indptr), shape=(M, M))
    # A^2 counts common neighbours of every pair; masked by A, only the edges' with any remain, and A added back
    # gives every edge 1 + its count, on A's own (row-sorted) entries: aligned with nbr, no search needed
    S = A.multiply(A @ A).tocsr() + A
    S.sort_indices()
    return (S.data - 1).astype(np.float64)


def length_matches(a: np.ndarray, b: np.ndarray, lo2: np.ndarray, hi2: np.ndarray, cand: np.ndarray,
                   points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The candidate pairs ``(cand[a[p], r1], cand[b[p], r2])`` (both >= 0) whose points lie apart by a squared
    distance l2 with ``lo2[p] < l2 < hi2[p]``: three (Q,) int64 arrays, the pair p and the correspondences
    ``a[p] * k + r1`` and ``b[p] * k + r2``, by p, then r1, then r2.

    a, b : (P,) int64 rows of ``cand`` (scene keypoints); lo2, hi2 : (P,) float32 (m^2); cand : (S, k) int64
    candidate model keypoints, -1 where there is none; points : (K, 3) float32 model keypoints (m). l2 is summed in
    float32 as ``(bx - ax)^2``, then ``+= (by - ay)^2`` and ``+= (bz - az)^2``, as the compiled
    ``compatible_pairs`` sums it. In numpy: the graph's path where the kernel was not built.
    """
    a, b = np.ascontiguousarray(a, dtype=np.int64), np.ascontiguousarray(b, dtype=np.int64)
    lo2, hi2 = np.ascontiguousarray(lo2, dtype=np.float32), np.ascontiguousarray(hi2, dtype=np.float32)
    cand = np.ascontiguousarray(cand, dtype=np.int64)
    xyz = [np.ascontiguousarray(points[:, i], dtype=np.float32) for i in range(3)]
    k = cand.shape[1]
    # one coordinate array per axis with a NaN at the end, which a missing candidate (-1) reads: its length is NaN
    # and fails the test, as does the same model keypoint at both ends (length 0, and lo2 >= 0)
    mx, my, mz = (np.append(c, np.float32(np.nan)) for c in xyz)
    ca, cb = cand[a], cand[b]  # (P, k)
    ax, ay, az, bx, by, bz = mx[ca], my[ca], mz[ca], mx[cb], my[cb], mz[cb]
    lo, hi = lo2[:, None], hi2[:, None]
    codes = []
    for r1 in range(k):
        d = bx - ax[:, r1, None]
        l2 = d * d
        d = by - ay[:, r1, None]
        l2 += d * d
        d = bz - az[:, r1, None]
        l2 += d * d
        p, r2 = np.divmod(np.flatnonzero((l2 > lo) & (l2 < hi)), k)
        codes.append((p * k + r1) * k + r2)
    q, r2 = np.divmod(np.sort(np.concatenate(codes)), k)
    p, r1 = np.divmod(q, k)
    return p, a[p] * k + r1, b[p] * k + r2


def compatible_pairs(a: np.ndarray, b: np.ndarray, lo2: np.ndarray, hi2: np.ndarray, cand: np.ndarray,
                     points: np.ndarray, *, normals: np.ndarray, angles: np.ndarray, tol: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The candidate pairs of ``length_matches`` sorted by the angle test, in the compiled kernel (which must be
    built: ``compiled()``). A pair's angles agree when ``|f - arccos(c)| < tol`` for each of the scene pair's angles
    ``angles`` (P, 3) float32 (rad: the normals' angle, n1's and n2's angle with the pair vector) and the model
    pair's cosines c, in float32 as ``grouping.common`` tests them in numpy. The kernel computes c in double and
    decides only where float32 rounding cannot change the verdict (``pcdet/_graph.c`` gives the margins).

    Returns ``(ia, ib)``, the correspondences of the pairs whose angles surely agree, and ``(p, ua, ub)``, the pairs
    too close to call (for numpy to decide); pairs whose angles surely disagree are left out. Each (n,) int64, by p,
    r1, r2. normals : (K, 3) unit model normals (float32); the other arguments as for ``length_matches``."""
    if _graph is None:
        raise RuntimeError("compatible_pairs needs the compiled kernel (pcdet._graph), which was not built")
    a, b = np.ascontiguousarray(a, dtype=np.int64), np.ascontiguousarray(b, dtype=np.int64)
    lo2, hi2 = np.ascontiguousarray(lo2, dtype=np.float32), np.ascontiguousarray(hi2, dtype=np.float32)
    angles = np.ascontiguousarray(angles, dtype=np.float32)
    cand = np.ascontiguousarray(cand, dtype=np.int64)
    xyz = [np.ascontiguousarray(points[:, i], dtype=np.float32) for i in range(3)]
    nrm = [np.ascontiguousarray(normals[:, i], dtype=np.float32) for i in range(3)]
    sure, left = _graph.compatible_pairs(a, b, lo2, hi2, angles, float(np.float32(tol)), cand, *xyz, *nrm,
                                         cand.shape[1])
    ia, ib = np.frombuffer(sure, np.int64).reshape(2, -1)
    p, ua, ub = np.frombuffer(left, np.int64).reshape(3, -1)
    return ia, ib, p, ua, ub
