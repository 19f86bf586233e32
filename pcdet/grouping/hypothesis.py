"""The result of grouping: one pose hypothesis for one model instance."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Hypothesis:
    """``T_scene_model`` (4, 4) from the correspondences ``inliers`` (indices ``s * k + r`` into the model's
    candidate table) of model ``model_index`` (position in the library). The scene frame is the camera's in
    detection and the target cloud's in registration. ``group``: how many correspondences the grouper proposed
    it from (Hough: voters of the peak that agree on the rotation; GC: the consistent set; RANSAC: the
    consensus set), before the robust refit that gives ``inliers``."""

    model_index: int
    T_scene_model: np.ndarray
    inliers: np.ndarray
    group: int = 0

    @property
    def n_inliers(self) -> int:
        """Number of correspondences that agree with the pose."""
        return int(len(self.inliers))
