"""The Linear Combination Method (Ullman and Basri; Liu and Wang, "Recognition of 3D Objects from 2D Images -
Some Issues").

Under orthographic projection, the x coordinate of a point in a novel view of a rigid object is a linear
combination of its x coordinates in three model views, and likewise for y:

    x0 = alpha_x x1 + beta_x x2 + gamma_x x3 + delta_x        y0 = alpha_y y1 + beta_y y2 + gamma_y y3 + delta_y

Four corresponding points fix the four coefficients of each (more: least squares). The fitted combination
predicts where further model points must appear in the unknown image; the object matches when every predicted
point lies within a threshold of the observed one. An articulated object is a set of rigid parts, each with
its own combination; it matches only if every part does.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError


def _as_points(a, name: str) -> np.ndarray:
    a = np.asarray(a, float)
    if a.ndim != 2 or a.shape[1] != 2:
        raise InputError(f"{name} must be an (N, 2) array of image points, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} holds NaN or infinite coordinates")
    return a


class LinearCombination:
    """Fit with ``LinearCombination().fit(views, points)``.

    coef_x, coef_y : (4,) alpha, beta, gamma, delta for x and for y (after ``fit``).
    rank_x, rank_y : rank of each coordinate's system (4 when the coefficients are unique).
    """

    def __init__(self):
        self.coef_x: np.ndarray | None = None
        self.coef_y: np.ndarray | None = None
        self.rank_x = self.rank_y = 0
        self.n_views = 0

    def fit(self, views, points, allow_degenerate: bool = False) -> "LinearCombination":
        """views : >= 3 arrays (N, 2), the same N feature points in each model image; points : (N, 2) those
        points in the unknown image, N >= 4 (exact for 4, least squares above). With more than three views,
        each coordinate gets one coefficient per view plus the offset.

        When the model points make a coordinate's system singular (e.g. their y values are linearly dependent
        across the views), the coefficients are not unique: ``ValueError``, or with ``allow_degenerate`` the
        minimum-norm least-squares solution (``rank_x`` / ``rank_y`` tell)."""
        views = [_as_points(v, f"views[{i}]") for i, v in enumerate(views)]
        pts = _as_points(points, "points")
        if len(views) < 3:
            raise InputError(f"the linear combination method needs at least 3 model views, got {len(views)}")
        n = len(pts)
        if any(len(v) != n for v in views):
            raise InputError(f"every view needs the same {n} points as the unknown image, got "
                             f"{[len(v) for v in views]}")
        if n < len(views) + 1:
            raise InputError(f"{len(views) + 1} corresponding points are needed for {len(views)} views, got {n}")
        coefs, ranks = [], []
        for c, axis in ((0, "x"), (1, "y")):
            A = np.column_stack([v[:, c] for v in views] + [np.ones(n)])
            ranks.append(int(np.linalg.matrix_rank(A)))
            if ranks[-1] < A.shape[1] and not allow_degenerate:
                raise InputError(f"the model points' {axis} coordinates are linearly dependent across the views "
                                 f"(rank {ranks[-1]} of {A.shape[1]}): the {axis} coefficients are not unique")
            coefs.append(np.linalg.lstsq(A, pts[:, c], rcond=None)[0])
        self.coef_x, self.coef_y = coefs
        self.rank_x, self.rank_y = ranks
        self.n_views = len(views)
        return self

    def predict(self, view_points) -> np.ndarray:
        """view_points : one (M, 2) array per model view, M further points -> (M, 2) predicted positions in the
        unknown image."""
        if self.coef_x is None:
            raise RuntimeError("fit() first")
        vp = [_as_points(v, f"view_points[{i}]") for i, v in enumerate(view_points)]
        if len(vp) != self.n_views:
            raise InputError(f"fitted with {self.n_views} views, got {len(vp)}")
        X = np.column_stack([v[:, 0] for v in vp] + [np.ones(len(vp[0]))])
        Y = np.column_stack([v[:, 1] for v in vp] + [np.ones(len(vp[0]))])
        return np.column_stack([X @ self.coef_x, Y @ self.coef_y])

    def residuals(self, view_points, observed) -> np.ndarray:
        """(M, 2) absolute differences |predicted - observed| in x and y."""
        return np.abs(self.predict(view_points) - _as_points(observed, "observed"))

    def matches(self, view_points, observed, threshold: float) -> bool:
        """True when every predicted coordinate is within ``threshold`` of the observed one (the paper's test)."""
        return bool(np.all(self.residuals(view_points, observed) < threshold))


@dataclass
class ArticulatedModel:
    """Named rigid parts, each with its model views (a list of >= 3 (N, 2) arrays) of its feature points."""

    parts: dict[str, list] = field(default_factory=dict)

    def fit(self, points: dict[str, np.ndarray], allow_degenerate: bool = False) -> dict[str, LinearCombination]:
        """One ``LinearCombination`` per part from the unknown image's points of that part."""
        missing = set(self.parts) - set(points)
        if missing:
            raise InputError(f"no points for part(s) {sorted(missing)}")
        return {name: LinearCombination().fit(views, points[name], allow_degenerate)
                for name, views in self.parts.items()}

    def match(self, points: dict[str, np.ndarray], check: dict[str, tuple], threshold: float
              ) -> tuple[bool, dict[str, bool]]:
        """Fit each part on ``points``, then test it on ``check[part] = (view_points, observed)``. The object
        matches only if every part does; returns (overall, per part)."""
        fits = self.fit(points)
        per = {name: fits[name].matches(*check[name], threshold) for name in self.parts}
        return all(per.values()), per
