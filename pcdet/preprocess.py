"""Scene preprocessing: depth range crop, voxel grid, dominant-plane removal, clusters, normals toward the camera."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cloud import Plane, estimate_normals, euclidean_clusters, segment_plane, voxel_downsample
from .config import PreprocessConfig
from .errors import InputError
from .frame import Frame


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


def preprocess(frame: Frame, cfg: PreprocessConfig, seed: int = 0) -> SceneCloud:
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
        plane = segment_plane(pts, cfg.plane_distance, cfg.plane_iterations, rng=seed)
        if plane is not None:
            # drop the plane and whatever lies beyond it (under the table, seen through gaps)
            keep = pts @ plane.normal + plane.offset > cfg.plane_distance
            pts = pts[keep]
    labels = euclidean_clusters(pts, cfg.cluster_tolerance, cfg.min_cluster_points)
    pts, labels = pts[labels >= 0], labels[labels >= 0]
    normals = estimate_normals(pts, cfg.normal_radius, cfg.normal_max_nn) if len(pts) >= 3 else np.zeros((0, 3))
    return SceneCloud(pts, normals, labels, plane, n_input)
