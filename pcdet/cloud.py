"""Point-cloud operations on numpy arrays: voxel grid, normals, dominant plane, Euclidean clusters.

All functions are deterministic: the voxel grid orders its output by voxel key, the plane RANSAC draws from a
seeded generator, and clusters are numbered by their smallest point index.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def voxel_downsample(points: np.ndarray, voxel: float, normals: np.ndarray | None = None,
                     representatives: bool = True) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Average the points (and normals) that fall in each cubic voxel of side ``voxel`` (m).

    Returns ``(points (M, 3), normals (M, 3) or None, index (M,) or None)`` where ``index`` is, for each voxel,
    the input point closest to the voxel's mean (a real sample to hang features on), when ``representatives``.
    """
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0:
        return points.reshape(0, 3), None if normals is None else normals.reshape(0, 3), np.zeros(0, np.int64)
    keys = np.floor(points / voxel).astype(np.int64)
    keys -= keys.min(axis=0)
    dims = keys.max(axis=0) + 1
    lin = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    order = np.argsort(lin, kind="stable")
    sl = lin[order]
    first = np.ones(len(sl), bool)
    first[1:] = sl[1:] != sl[:-1]
    inv = np.empty(len(lin), np.int64)
    inv[order] = np.cumsum(first) - 1
    counts = np.bincount(inv)
    m = len(counts)
    mean = np.stack([np.bincount(inv, weights=points[:, i], minlength=m) for i in range(3)], axis=1)
    mean /= counts[:, None]
    nout = None
    if normals is not None:
        nsum = np.stack([np.bincount(inv, weights=normals[:, i], minlength=m) for i in range(3)], axis=1)
        norm = np.linalg.norm(nsum, axis=1, keepdims=True)
        nout = np.divide(nsum, norm, out=np.zeros_like(nsum), where=norm > 0)
    if not representatives:
        return mean, nout, None
    # representative: the point nearest to its voxel mean (ties: lowest index, by stable lexsort)
    d2 = ((points - mean[inv]) ** 2).sum(axis=1)
    order = np.lexsort((np.arange(len(points)), d2, inv))
    first = np.ones(len(order), bool)
    first[1:] = inv[order[1:]] != inv[order[:-1]]
    rep = order[first]
    return mean, nout, rep


def estimate_normals(points: np.ndarray, radius: float, max_nn: int = 30,
                     viewpoint: np.ndarray | None = np.zeros(3)) -> np.ndarray:
    """Unit normals (N, 3) from the covariance of neighbours within ``radius`` (m), at most ``max_nn``.

    With a ``viewpoint`` (default: the camera origin) every normal is flipped to face it.
    """
    from ._o3d import o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=max_nn))
    n = np.asarray(pc.normals).copy()
    if viewpoint is not None:
        flip = ((np.asarray(viewpoint) - points) * n).sum(axis=1) < 0
        n[flip] *= -1
    return n


def outward_normals(points: np.ndarray, radius: float, max_nn: int = 30) -> np.ndarray:
    """Unit normals (N, 3) of an unoriented cloud (a scanned model, say), oriented consistently along the
    surface (Open3D's tangent-plane propagation) and then, as a whole, away from the centroid (outward for
    closed objects and for single views of convex-ish ones)."""
    from ._o3d import o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pc.normals = o3d.utility.Vector3dVector(estimate_normals(points, radius, max_nn, viewpoint=None))
    if len(points) > 10:
        pc.orient_normals_consistent_tangent_plane(10)
    n = np.asarray(pc.normals).copy()
    if ((points - points.mean(axis=0)) * n).sum(axis=1).mean() < 0:
        n = -n
    return n


def diameter(points: np.ndarray) -> float:
    """Largest distance between two of the (N, 3) points (m), over their convex hull."""
    from scipy.spatial import ConvexHull

    points = np.asarray(points, float)
    try:
        hull = points[ConvexHull(points).vertices]
    except Exception:  # flat or degenerate sets: fall back on all points (qhull's errors are not user-facing)
        hull = points
    if len(hull) > 3000:
        hull = hull[np.linspace(0, len(hull) - 1, 3000).astype(int)]
    d2 = ((hull[:, None, :] - hull[None, :, :]) ** 2).sum(-1)
    return float(np.sqrt(d2.max()))


@dataclass(frozen=True)
class Plane:
    """Plane ``normal . x + offset = 0`` (unit normal toward the camera) and the indices of its inliers."""

    normal: np.ndarray
    offset: float
    inliers: np.ndarray


def segment_plane(points: np.ndarray, distance: float, iterations: int = 200,
                  rng: np.random.Generator | int = 0, min_inliers: int = 100) -> Plane | None:
    """Dominant plane by RANSAC, refit by least squares on its inliers; ``None`` when none has enough support."""
    rng = np.random.default_rng(rng)
    n = len(points)
    if n < max(3, min_inliers):
        return None
    # score on a fixed subsample: the plane is large, so a few thousand points rank candidates reliably
    sub = points if n <= 4000 else points[np.linspace(0, n - 1, 4000).astype(np.int64)]
    idx = rng.integers(0, n, size=(iterations, 3))
    a, b, c = points[idx[:, 0]], points[idx[:, 1]], points[idx[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-9
    if not ok.any():
        return None
    normals = normals[ok] / norms[ok, None]
    offsets = -(normals * a[ok]).sum(axis=1)
    support = (np.abs(sub @ normals.T + offsets) < distance).sum(axis=0)
    best = int(np.argmax(support))
    nrm, off = normals[best], offsets[best]
    inl = np.flatnonzero(np.abs(points @ nrm + off) < distance)
    if len(inl) < min_inliers:
        return None
    centroid = points[inl].mean(axis=0)
    _, _, vt = np.linalg.svd(points[inl] - centroid, full_matrices=False)
    nrm = vt[2]
    if nrm @ centroid > 0:  # face the camera at the origin
        nrm = -nrm
    off = -float(nrm @ centroid)
    inl = np.flatnonzero(np.abs(points @ nrm + off) < distance)
    return Plane(nrm, off, inl)


def support_region(points: np.ndarray, plane: Plane, max_height: float, min_height: float) -> np.ndarray:
    """(N,) bool: the points that stand on ``plane``: between ``min_height`` and ``max_height`` m above it
    (on the camera's side) and inside the outline of its inliers (their convex hull, in the plane)."""
    from scipy.spatial import ConvexHull, Delaunay

    n = plane.normal
    u = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    h = points @ n + plane.offset
    out = (h > min_height) & (h < max_height)
    test = np.flatnonzero(out)  # the outline test only for points at a height that could stand on the plane
    uv = np.stack([points @ u, points @ v], axis=1)
    try:
        outline = uv[plane.inliers][ConvexHull(uv[plane.inliers]).vertices]
        out[test] = Delaunay(outline).find_simplex(uv[test]) >= 0
    except Exception:  # qhull: a degenerate (collinear) plane has no outline; nothing stands on it
        out[:] = False
    return out


def euclidean_clusters(points: np.ndarray, tolerance: float, min_size: int = 1) -> np.ndarray:
    """Label (N,) int64 of connected components with links shorter than ``tolerance`` (m); -1 for clusters
    smaller than ``min_size``. Labels are numbered by decreasing cluster size (ties by first point)."""
    n = len(points)
    if n == 0:
        return np.zeros(0, np.int64)
    pairs = cKDTree(points).query_pairs(tolerance, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, lab = connected_components(g, directed=False)
    sizes = np.bincount(lab)
    first = np.full(len(sizes), n)
    np.minimum.at(first, lab, np.arange(n))
    order = np.lexsort((first, -sizes))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    out = rank[lab].astype(np.int64)
    out[sizes[lab] < min_size] = -1
    return out
