"""The result of grouping: one pose hypothesis for one model instance."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Hypothesis:
    """``T_cam_model`` (4, 4) from the correspondences ``inliers`` (indices into the model's correspondence
    list) of model ``model_index`` (position in the library). ``group``: how many correspondences the grouper
    proposed it from (Hough: voters of the peak that agree on the rotation; GC: the consistent set; RANSAC:
    the consensus set), before the robust refit that gives ``inliers``."""

    model_index: int
    T_cam_model: np.ndarray
    inliers: np.ndarray
    group: int = 0

    @property
    def n_inliers(self) -> int:
        return int(len(self.inliers))
