"""Scene preprocessing: depth range crop, voxel grid, dominant-plane removal, clusters, normals toward the camera."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cloud import (
    Plane,
    estimate_normals,
    euclidean_clusters,
    segment_plane,
    support_region,
    voxel_downsample,
)
from .errors import ConfigError, InputError
from .frame import Frame
from .params import check_positive, param


@dataclass(frozen=True)
class PreprocessConfig:
    """Depth range, voxel grid, normals, supporting-plane removal and Euclidean clusters of the scene."""

    min_depth: float = param(0.1, "m; scene points nearer than this are dropped")
    max_depth: float = param(2.5, "m; scene points farther than this are dropped")
    voxel: float = param(0.004, "m; voxel grid of the scene and of model samples")
    normal_radius: float = param(0.01, "m; neighbourhood for normals (scene, model views)")
    normal_max_nn: int = param(30, "most neighbours used for a normal")
    remove_plane: bool = param(True, "remove the supporting plane (table, floor) and what lies beyond it")
    plane_distance: float = param(0.008, "m; points this close to the plane belong to it")
    plane_iterations: int = param(300, "RANSAC draws for the plane")
    support: bool = param(True, "keep only what stands on the supporting plane: above it, inside its outline, no "
                                "higher than max_height (objects on a table; false: keep all off the plane)")
    support_planes: int = param(3, "largest planes tried as the support; the one with most points standing on it "
                                   "wins (the dominant plane of a room is often a wall or the floor)")
    max_height: float = param(0.0, "m; tallest object above the support (0: 1.2 x the largest model diameter)")
    cluster_tolerance: float = param(0.012, "m; points closer than this join one Euclidean cluster")
    min_cluster_points: int = param(40, "clusters with fewer points are dropped as clutter")

    def __post_init__(self):
        check_positive(self, "voxel", "normal_radius", "normal_max_nn", "plane_distance", "cluster_tolerance",
                       "support_planes")
        if self.max_height < 0:
            raise ConfigError(f"PreprocessConfig.max_height must be >= 0, got {self.max_height}")
        if not 0 <= self.min_depth < self.max_depth:
            raise ConfigError(f"need 0 <= min_depth < max_depth, got {self.min_depth}, {self.max_depth}")


@dataclass
class SceneCloud:
    """The part of a frame that objects are searched in (camera frame, metres).

    points, normals : (N, 3) float64 voxel-grid points off the dominant plane, normals facing the camera.
    labels : (N,) int64 Euclidean cluster of each point (-1: too small a cluster, already dropped from points).
    plane : the removed dominant plane or None.
    n_input : valid depth pixels in the frame before any step.
    """

    points: np.ndarray
    normals: np.ndarray
    labels: np.ndarray
    plane: Plane | None
    n_input: int


def preprocess(frame: Frame, cfg: PreprocessConfig, seed: int = 0, *, model_size: float = 0.3,
               workers: int = 0) -> SceneCloud:
    """The frame's ``SceneCloud``: points in the depth range on a voxel grid, the supporting plane and what lies
    beyond it removed (with ``cfg.support``, also everything that does not stand on it), small clusters
    dropped, normals toward the camera. ``seed`` drives the plane RANSAC; ``model_size`` (m, the largest
    diameter searched for) sets the height kept above the support when ``cfg.max_height`` is 0; ``workers``:
    threads of the normals (0: every core; the same result on any number)."""
    pts, _ = frame.points()
    n_input = len(pts)
    src = frame.info.get("source")
    if n_input == 0:
        raise InputError("frame has no valid depth pixel", src)
    z = pts[:, 2]
    pts = pts[(z >= cfg.min_depth) & (z <= cfg.max_depth)]
    if len(pts) == 0:
        raise InputError(f"no point between min_depth {cfg.min_depth} m and max_depth {cfg.max_depth} m "
                         f"(depths span {z.min():.3f}..{z.max():.3f} m): wrong depth units?", src)
    pts, _, _ = voxel_downsample(pts, cfg.voxel, representatives=False)
    plane = None
    if cfg.remove_plane:
        plane, region = _support(pts, cfg, seed, cfg.max_height or 1.2 * model_size)
        if plane is not None:
            # drop the plane and whatever lies beyond it (under the table, seen through gaps)
            keep = region if region is not None else pts @ plane.normal + plane.offset > cfg.plane_distance
            pts = pts[keep]
    labels = euclidean_clusters(pts, cfg.cluster_tolerance, cfg.min_cluster_points)
    pts, labels = pts[labels >= 0], labels[labels >= 0]
    normals = (estimate_normals(pts, cfg.normal_radius, cfg.normal_max_nn, workers=workers) if len(pts) >= 3
               else np.zeros((0, 3)))
    return SceneCloud(pts, normals, labels, plane, n_input)


def _support(pts: np.ndarray, cfg: PreprocessConfig, seed: int, max_height: float
             ) -> tuple[Plane | None, np.ndarray | None]:
    """The supporting plane and, with ``cfg.support``, the mask of the points standing on it. Without support
    the plane is the dominant one (seeded by ``seed``); with it, of the ``support_planes`` largest planes
    (each found among the points the earlier ones left), the one with most points standing on it."""
    first = segment_plane(pts, cfg.plane_distance, cfg.plane_iterations, rng=seed)
    if first is None or not cfg.support:
        return first, None
    best, best_region, rest, plane = None, None, np.arange(len(pts)), first
    for k in range(cfg.support_planes):
        if k:
            found = segment_plane(pts[rest], cfg.plane_distance, cfg.plane_iterations, rng=seed + k)
            if found is None:
                break
            plane = Plane(found.normal, found.offset, rest[found.inliers])
        region = support_region(pts, plane, max_height, cfg.plane_distance)
        if best is None or region.sum() > best_region.sum():
            best, best_region = plane, region
        rest = np.setdiff1d(rest, plane.inliers, assume_unique=True)
        if len(rest) < 100:
            break
    return best, best_region
