"""Correspondence grouping: turn candidate matches into object hypotheses (one per instance).

Every grouper follows one protocol (``Grouper``) and sits in the registry ``GROUPERS``; its parameters are
the section ``[grouping.<name>]`` of a pipeline file. A new grouper is one new module and one registry line.
"""
from __future__ import annotations

from dataclasses import dataclass, make_dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from ..errors import ConfigError
from ..params import check_positive, param
from .consistency import ConsistencyGrouper
from .hough import HoughGrouper
from .hypothesis import Hypothesis
from .ransac import RansacGrouper

if TYPE_CHECKING:
    from ..matching import Candidates
    from ..prepared_model import PreparedModel
    from ..scene import SceneKeypoints


class Grouper(Protocol):
    """name : the registry key; Config : the frozen dataclass of its own parameters; needs_lrfs : whether
    ``group`` reads ``scene.lrfs`` (the detector computes them only then). Built from the whole
    ``GroupingConfig`` (the shared fields and its own section)."""

    name: str
    Config: type
    needs_lrfs: bool

    def __init__(self, cfg: GroupingConfig): ...

    def group(self, scene: "SceneKeypoints", model: "PreparedModel", candidates: "Candidates",
              rng: np.random.Generator, *, workers: int = 1) -> list[Hypothesis]:
        """Pose hypotheses of ``model`` in ``scene`` from ``candidates`` (rows aligned with ``scene``'s
        keypoints); ``rng`` is the only source of randomness; ``workers``: threads it may use (the result is
        the same for any number)."""


GROUPERS: dict[str, type] = {
    "ransac": RansacGrouper,
    "gc": ConsistencyGrouper,
    "hough": HoughGrouper,
}


@dataclass(frozen=True)
class GroupingCommon:
    """The grouping fields every grouper reads; each grouper's own fields are in its sub-table."""

    method: str = param("ransac", f"correspondence grouping: {', '.join(repr(k) for k in GROUPERS)}")
    inlier_distance: float = param(0.01, "m; a correspondence within this of the posed model point is an inlier")
    min_inliers: int = param(5, "distinct scene keypoints a hypothesis needs")
    grid_per_diameter: float = param(12.0, "scene keypoints used for grouping are at least diameter / this apart")
    max_keypoints: int = param(1500, "scene keypoints each model groups at most: those whose candidates are nearest in "
                                  "FPFH space, on the matching.screen_eps search (0: all)")
    distinct: int = param(32, "with targets and max_keypoints: a keypoint's candidates' distance is divided by its "
                             "distance to its this-many-th nearest scene keypoint in FPFH space before the nearest "
                             "are chosen, so that keypoints like much of the scene (walls, table tops) give way to "
                             "unusual ones (0: the distance alone, as always without targets: there unusual "
                             "clutter gave false detections)")
    look_alike: float = param(0.003, "m; models of one shape at other sizes (each centred on its bounding box in "
                                     "its own frame, their samples this close on average at the smaller one's size, "
                                     "sizes under 1.25 times apart) are grouped once, for the family's middle-sized "
                                     "member, whose best raw poses get the coarse ICP, and every member takes "
                                     "those coarse poses (0: each model grouped on its own)")

    def __post_init__(self):
        if self.method not in GROUPERS:
            raise ConfigError(f"grouping method {self.method!r} is not available; choose one of "
                              f"{', '.join(repr(k) for k in GROUPERS)}")
        check_positive(self, "inlier_distance", "min_inliers", "grid_per_diameter")
        if self.max_keypoints < 0:
            raise ConfigError(f"GroupingConfig.max_keypoints must be >= 0, got {self.max_keypoints}")
        if self.distinct < 0:
            raise ConfigError(f"GroupingConfig.distinct must be >= 0 (0: off), got {self.distinct}")
        if self.look_alike < 0:
            raise ConfigError(f"GroupingConfig.look_alike must be >= 0 (0: off), got {self.look_alike}")


# the shared fields plus one nested section per registered grouper: a new grouper needs no edit here
GroupingConfig = make_dataclass(
    "GroupingConfig",
    [(name, g.Config, param(g.Config, f"options of the {name!r} grouper")) for name, g in GROUPERS.items()],
    bases=(GroupingCommon,), frozen=True,
    namespace={"__doc__": "Grouping: the shared fields, and one sub-table of options per grouper."})
GroupingConfig.__module__ = __name__  # pickled by name (process pools, Ray)


def make_grouper(cfg: GroupingConfig) -> Grouper:
    """The grouper ``cfg.method`` names, built from ``cfg``."""
    return GROUPERS[cfg.method](cfg)


__all__ = ["GROUPERS", "Grouper", "GroupingConfig", "Hypothesis", "make_grouper"]
