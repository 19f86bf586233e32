"""Keypoint selection: one real sample per voxel of side ``spacing`` (default), or ISS."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .cloud import voxel_downsample
from .errors import ConfigError
from .params import check_positive, param


@dataclass(frozen=True)
class KeypointConfig:
    """How keypoints are chosen on scene and model clouds."""

    method: str = param("voxel", "'voxel' (one sample per cell of `spacing`) or 'iss'")
    spacing: float = param(0.008, "m; keypoint spacing for the voxel method")
    iss_salient_radius: float = param(0.012, "m; ISS salient radius")
    iss_non_max_radius: float = param(0.008, "m; ISS non-maximum suppression radius")

    def __post_init__(self):
        if self.method not in ("voxel", "iss"):
            raise ConfigError(f"KeypointConfig.method must be 'voxel' or 'iss', got {self.method!r}")
        check_positive(self, "spacing", "iss_salient_radius", "iss_non_max_radius")


def select_keypoints(points: np.ndarray, cfg: KeypointConfig) -> np.ndarray:
    """(K,) int64 sorted indices into ``points`` (N, 3) of the keypoints."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    if cfg.method == "voxel":
        _, _, rep = voxel_downsample(points, cfg.spacing)
        return np.sort(rep)
    from ._o3d import o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    kp = o3d.geometry.keypoint.compute_iss_keypoints(pc, salient_radius=cfg.iss_salient_radius,
                                                     non_max_radius=cfg.iss_non_max_radius)
    kpts = np.asarray(kp.points)
    if len(kpts) == 0:
        return np.zeros(0, np.int64)
    _, idx = cKDTree(points).query(kpts)
    return np.unique(idx.astype(np.int64))


def voxel_keypoint_levels(points: np.ndarray, steps) -> tuple[np.ndarray, dict[float, np.ndarray]]:
    """Voxel keypoints at several spacings at once: each step's set is exactly ``select_keypoints`` at that
    spacing (the sample nearest each occupied voxel's mean), so a model grouping one of them sees the keypoints
    it would see searched alone; the descriptors are then computed once, on the union.

    points : (N, 3) m; steps : positive spacings (m). Returns ``(kp, levels)``: ``kp`` (K,) int64 ascending
    indices into ``points`` of every step's samples, and ``levels[step]`` the ascending positions in ``kp`` of
    that step's samples.
    """
    steps = sorted({float(s) for s in steps})
    if len(points) == 0 or not steps:
        return np.zeros(0, np.int64), {s: np.zeros(0, np.int64) for s in steps}
    per = {s: np.sort(voxel_downsample(points, s)[2]) for s in steps}
    kp = np.unique(np.concatenate(list(per.values())))
    return kp, {s: np.searchsorted(kp, idx) for s, idx in per.items()}
