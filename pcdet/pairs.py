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
    length = np.sqrt(np.einsum("...i,...i->...", d, d))
    inv = 1.0 / np.maximum(length, 1e-12)
    f = np.empty(length.shape + (4,), np.float32)
    f[..., 0] = length
    f[..., 1] = np.arccos(np.clip(np.einsum("...i,...i->...", n1, d) * inv, -1, 1))
    f[..., 2] = np.arccos(np.clip(np.einsum("...i,...i->...", n2, d) * inv, -1, 1))
    f[..., 3] = np.arccos(np.clip(np.einsum("...i,...i->...", n1, n2), -1, 1))
    return f


@dataclass
class ScenePairs:
    """Unordered pairs (a < b) of scene keypoints closer than ``radius`` and in the same cluster, with their
    features (P, 4) computed in the order (a, b). The pairs come in no particular (but a deterministic) order."""

    a: np.ndarray
    b: np.ndarray
    features: np.ndarray


def scene_pairs(points, normals, labels, radius: float) -> ScenePairs:
    """Pairs of scene keypoints (points, normals (S, 3), labels (S,)) within ``radius`` (m)."""
    points = np.asarray(points, float)
    extent = np.ptp(points, axis=0) if len(points) else np.zeros(3)
    if np.linalg.norm(extent) <= radius:  # every pair is within reach (a whole scan in registration, say)
        a, b = np.triu_indices(len(points), 1)
    else:
        # in the KD-tree's own order: deterministic, and no consumer depends on it (the graph is sorted)
        pairs = cKDTree(points).query_pairs(radius, output_type="ndarray").astype(np.int64)
        a, b = pairs[:, 0], pairs[:, 1]
    if len(a) == 0:
        z = np.zeros(0, np.int64)
        return ScenePairs(z, z, np.zeros((0, 4), np.float32))
    if np.ptp(labels) > 0:
        keep = labels[a] == labels[b]
        a, b = a[keep], b[keep]
    if len(points) <= 2000 and 4 * len(a) >= len(points) ** 2:
        # most of all pairs (a whole scan in registration): read their products off (S, S) matrices, 3x faster
        # than gathering (P, 3) rows; for a scene's few near pairs the matrices would cost more than they save
        return ScenePairs(a, b, _features_from_products(points, normals, a, b))
    return ScenePairs(a, b, pair_features(points[a], normals[a], points[b], normals[b]))


def _features_from_products(points: np.ndarray, normals: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``pair_features`` of the pairs (a, b) of (S, 3) points and normals, from the products of all of them:
    |p_b - p_a|^2 = |p_a|^2 + |p_b|^2 - 2 p_a . p_b and n . (p_b - p_a) = n . p_b - n . p_a (centred first, so
    that no large coordinate cancels)."""
    p = points - points.mean(axis=0)
    S = len(p)
    pp, npm = (p @ p.T).ravel(), (normals @ p.T).ravel()  # (S * S): p_i . p_j and n_i . p_j at i * S + j
    ab, diag = a * S + b, np.arange(S) * (S + 1)
    ba = b * S + a
    sq = pp[diag]
    length = np.sqrt(np.maximum(sq[a] + sq[b] - 2 * pp[ab], 0.0))
    inv = 1.0 / np.maximum(length, 1e-12)
    f = np.empty((len(a), 4), np.float32)
    f[:, 0] = length
    f[:, 1] = np.arccos(np.clip((npm[ab] - npm[diag][a]) * inv, -1, 1))
    f[:, 2] = np.arccos(np.clip((npm[diag][b] - npm[ba]) * inv, -1, 1))
    f[:, 3] = np.arccos(np.clip((normals @ normals.T).ravel()[ab], -1, 1))
    return f

