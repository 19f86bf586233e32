"""Point-pair features (Drost et al. 2010) and the scene keypoint pairs the groupers test them on.

The feature of an ordered pair (p1, n1), (p2, n2) with d = p2 - p1 is
(|d|, angle(n1, d), angle(n2, d), angle(n1, n2)): four numbers that a rigid motion keeps. Two correspondences
are compatible when their scene pair and their model pair have the same feature within tolerances.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


def pair_features(p1, n1, p2, n2) -> np.ndarray:
    """(..., 4) float32 features of pairs given as (..., 3) arrays: length (m) and three angles (rad)."""
    d = p2 - p1
    length = np.linalg.norm(d, axis=-1)
    u = d / np.maximum(length, 1e-12)[..., None]
    f = np.stack([length,
                  np.arccos(np.clip((n1 * u).sum(-1), -1, 1)),
                  np.arccos(np.clip((n2 * u).sum(-1), -1, 1)),
                  np.arccos(np.clip((n1 * n2).sum(-1), -1, 1))], axis=-1)
    return f.astype(np.float32)


@dataclass
class ScenePairs:
    """Unordered pairs (a < b) of scene keypoints closer than ``radius`` and in the same cluster, with their
    features (P, 4) computed in the order (a, b)."""

    a: np.ndarray
    b: np.ndarray
    features: np.ndarray


def scene_pairs(points, normals, labels, radius: float) -> ScenePairs:
    """Pairs of scene keypoints (points, normals (S, 3), labels (S,)) within ``radius`` (m)."""
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        z = np.zeros(0, np.int64)
        return ScenePairs(z, z, np.zeros((0, 4), np.float32))
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]  # query_pairs' order is not specified
    a, b = pairs[:, 0], pairs[:, 1]
    keep = labels[a] == labels[b]
    a, b = a[keep], b[keep]
    return ScenePairs(a, b, pair_features(points[a], normals[a], points[b], normals[b]))

