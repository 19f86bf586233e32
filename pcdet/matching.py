"""Descriptor matching between scene keypoints and each model of the library."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .errors import ConfigError
from .params import check_positive, param


@dataclass(frozen=True)
class MatchingConfig:
    """Descriptor matching: how many candidates per scene keypoint, ratio and mutual tests."""

    k: int = param(4, "candidate model keypoints kept per scene keypoint (nearest in FPFH space)")
    ratio: float = param(1.0, "Lowe ratio test on the nearest two (1.0: off, keep k)")
    mutual: bool = param(False, "keep only mutual nearest neighbours")

    def __post_init__(self):
        check_positive(self, "k")
        if not 0 < self.ratio <= 1:
            raise ConfigError(f"MatchingConfig.ratio must be in (0, 1] (1 disables the test), got {self.ratio}")


@dataclass
class Candidates:
    """Candidate matches for one model, as a table over scene keypoints.

    model : (S, k) int64 model keypoint index of the r-th candidate of scene keypoint s, -1 where none.
    distance : (S, k) float FPFH distance of each candidate (inf where none).
    Correspondence ``c = s * k + r`` names one entry.
    """

    model: np.ndarray
    distance: np.ndarray

    @property
    def k(self) -> int:
        """Candidates per scene keypoint (columns of the table)."""
        return self.model.shape[1]

    def __len__(self) -> int:
        return int((self.model >= 0).sum())

    def rows(self, index: np.ndarray) -> "Candidates":
        """The candidates of the scene keypoints ``index`` only (a ``SceneKeypoints`` view's ``index``)."""
        return Candidates(self.model[index], self.distance[index])


def match_features(scene_features: np.ndarray, model_features: np.ndarray, cfg: MatchingConfig, *,
                   model_tree: cKDTree | None = None, workers: int = 1) -> Candidates:
    """Each scene descriptor (S, 33) keeps its ``cfg.k`` nearest model descriptors (D, 33).

    With ``cfg.ratio < 1`` only the nearest is kept, and only when it is closer than ``ratio`` times the second
    (Lowe's test). With ``cfg.mutual`` a candidate is kept only if the scene descriptor is also the model
    descriptor's nearest.
    """
    S, D = len(scene_features), len(model_features)
    if S == 0 or D == 0:
        return Candidates(np.full((S, 1), -1, np.int64), np.full((S, 1), np.inf))
    tree = model_tree if model_tree is not None else cKDTree(model_features)
    k = min(cfg.k if cfg.ratio >= 1 else 2, D)
    dist, idx = tree.query(scene_features, k=k, workers=workers)  # exact search: same answer on any thread count
    dist, idx = dist.reshape(S, k), idx.reshape(S, k).astype(np.int64)
    if cfg.ratio < 1 and k >= 2:
        ok = dist[:, 0] < cfg.ratio * dist[:, 1]
        dist, idx = dist[:, :1].copy(), idx[:, :1].copy()
        idx[~ok, 0] = -1
        dist[~ok, 0] = np.inf
    if cfg.mutual:
        _, back = cKDTree(scene_features).query(model_features, k=1)
        rows = np.broadcast_to(np.arange(S)[:, None], idx.shape)
        bad = (idx >= 0) & (back[np.maximum(idx, 0)] != rows)
        idx[bad] = -1
        dist[bad] = np.inf
    return Candidates(idx, dist)
