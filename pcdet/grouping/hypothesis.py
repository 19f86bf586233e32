"""The result of grouping: one pose hypothesis for one model instance."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Hypothesis:
    """``T_cam_model`` (4, 4) from the correspondences ``inliers`` (indices into the model's correspondence
    list) of model ``model_index`` (position in the library)."""

    model_index: int
    T_cam_model: np.ndarray
    inliers: np.ndarray

    @property
    def n_inliers(self) -> int:
        return int(len(self.inliers))
