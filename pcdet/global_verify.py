"""Global hypothesis verification: choose the set of hypotheses that best explains the scene.

After Aldoma, Tombari, Di Stefano and Vincze (ECCV 2012), in the scene's point domain. Each candidate h (a
model at a refined pose) *explains* the scene points within ``explain_radius`` of its surface samples, and its
*clutter* is the scene points within ``clutter_radius`` of those it explains that it does not explain itself:
a model fitted to one face of something else leaves the rest of that thing unexplained next to it. For a
selection x of candidates, with c(p) the number of selected candidates explaining scene point p:

    f(x) = #{p : c(p) >= 1}                                   scene points explained
         - w_dup     * sum_p max(c(p) - 1, 0)                  points claimed twice (duplicates, rival models)
         - w_clutter * sum_{h in x} #{p in clutter(h) : c(p) = 0}   clutter left unexplained by every choice
         - w_viol    * sum_{h in x} v(h)                       see-through evidence, in point units

v(h) = explained(h) * violations / supported from the pixel-level check (``verify.verify``). The maximiser is
found by deterministic local search: start empty, apply the best single switch (add or drop one candidate)
while it raises f. Clutter that another selected candidate explains costs nothing, so neighbouring true
objects do not penalise each other.

What an object stands on is neither its clutter nor explained by it: with a supporting plane given, a scene point
that faces up like the plane (normal within ``SUPPORT_DEG``) and lies no higher above it than the placed model's
lowest sample (plus ``explain_radius``) is left out of h's explained points and of its clutter. On real tables
objects stand on books, magazines and boards a centimetre or two above the plane that preprocessing removed, and
that surface runs on under the object's base: counted as clutter it sinks true detections, and counted as
explained it lets a flat model laid into the board (a bracket fitted to a printed marker board) explain nothing
but its support and still be chosen.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .grid import within_any

if TYPE_CHECKING:
    from .cloud import Plane


@dataclass(frozen=True)
class GlobalTerms:
    """Per-candidate point sets (indices into the scene points) and the violation cost."""

    explained: list[np.ndarray]
    clutter: list[np.ndarray]
    violation: np.ndarray


SUPPORT_DEG = 30.0  # a surface facing up within this of the supporting plane's normal can carry an object


def candidate_terms(scene_points: np.ndarray, model_points: list[np.ndarray],
                    violation_ratio: np.ndarray, explain_radius: float, clutter_radius: float, *,
                    plane: "Plane | None" = None, scene_normals: np.ndarray | None = None) -> GlobalTerms:
    """scene_points : (N, 3) m; model_points : per candidate (M_h, 3) surface samples already at the pose (m);
    violation_ratio : (H,) violating / supported pixels of each candidate; plane : the supporting ``Plane``
    (unit normal toward the camera) or None, with ``scene_normals`` (N, 3): what a candidate stands on is neither
    its clutter nor explained by it (module docstring)."""
    height = level = None
    if plane is not None and scene_normals is not None:
        height = scene_points @ plane.normal + plane.offset
        level = scene_normals @ plane.normal >= np.cos(np.radians(SUPPORT_DEG))
    explained, clutter = [], []
    boxes = _SortedX(scene_points)
    for P in model_points:
        e = _near(boxes, P, explain_radius)
        rest = np.setdiff1d(_near(boxes, scene_points[e], clutter_radius, inclusive=True), e, assume_unique=True)
        if height is not None:
            base = float((P @ plane.normal).min()) + plane.offset + explain_radius
            support = level & (height <= base)
            e, rest = e[~support[e]], rest[~support[rest]]
        explained.append(e)
        clutter.append(rest)
    viol = np.array([len(e) for e in explained], float) * np.asarray(violation_ratio, float)
    return GlobalTerms(explained, clutter, viol)


class _SortedX:
    """The (N, 3) points sorted by x once, so that the points in an axis-aligned box are found from the slice of
    x's range alone (a search in the sorted x), not by testing every point of the frame."""

    def __init__(self, points: np.ndarray):
        self.points = points
        self.order = np.argsort(points[:, 0], kind="stable")
        self.x, self.y, self.z = (np.ascontiguousarray(points[self.order, i]) for i in range(3))

    def box(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Ascending indices of the points p with lo <= p <= hi (each (3,), m)."""
        i, j = np.searchsorted(self.x, lo[0], "left"), np.searchsorted(self.x, hi[0], "right")
        y, z = self.y[i:j], self.z[i:j]
        return np.sort(self.order[i:j][(y >= lo[1]) & (y <= hi[1]) & (z >= lo[2]) & (z <= hi[2])])


def _near(points: _SortedX, centres: np.ndarray, radius: float, *, inclusive: bool = False) -> np.ndarray:
    """Ascending indices of the points closer than ``radius`` (m; or as close, ``inclusive``) to any of the (C, 3)
    ``centres``: of the points in the box around the centres, those with a centre within reach (``grid.within_any``;
    one question per point of the box, where a ball query around each centre listed every neighbour many times
    over)."""
    if len(centres) == 0:
        return np.zeros(0, np.int64)
    box = points.box(centres.min(axis=0) - radius, centres.max(axis=0) + radius)
    bound = np.nextafter(radius, np.inf) if inclusive else radius
    return box[within_any(points.points[box], centres, bound)]


def select(terms: GlobalTerms, w_dup: float, w_clutter: float, w_viol: float, max_steps: int = 200, *,
           conflicts: np.ndarray | None = None, groups: list[int] | None = None,
           caps: dict[int, int] | None = None) -> tuple[list[int], float]:
    """Maximise f (module docstring) over subsets of the candidates. Returns (chosen indices in the order
    they were added, f). Ties are broken by the lower index, so the result depends only on the input.
    ``conflicts`` : optional (H, H) bool; two candidates marked there are never chosen together (two poses of
    one object that claim the same surface). ``groups`` (H,) and ``caps``: at most ``caps[g]`` candidates of
    group g are chosen together (the instances of each object given, BOP's localisation task)."""
    H = len(terms.explained)
    if H == 0:
        return [], 0.0
    # work on the union of the points any candidate touches, renumbered 0..U-1
    dom = np.unique(np.concatenate([*terms.explained, *terms.clutter]))
    E = [np.searchsorted(dom, e) for e in terms.explained]
    C = [np.searchsorted(dom, c) for c in terms.clutter]
    U = len(dom)

    def value(sel: np.ndarray) -> float:
        cnt = np.zeros(U, np.int64)
        for h in np.flatnonzero(sel):
            cnt[E[h]] += 1
        f = float(np.count_nonzero(cnt)) - w_dup * float(np.maximum(cnt - 1, 0).sum())
        for h in np.flatnonzero(sel):
            f -= w_clutter * float(np.count_nonzero(cnt[C[h]] == 0)) + w_viol * terms.violation[h]
        return f

    sel = np.zeros(H, bool)
    taken: dict[int, int] = dict.fromkeys(groups or (), 0)  # chosen per group (with caps)
    cur = 0.0
    order: list[int] = []
    for _ in range(max_steps):
        best, best_h = cur, -1
        for h in range(H):
            if not sel[h] and conflicts is not None and (conflicts[h] & sel).any():
                continue
            if not sel[h] and caps is not None and taken[groups[h]] >= caps.get(groups[h], H):
                continue
            sel[h] = ~sel[h]
            v = value(sel)
            sel[h] = ~sel[h]
            if v > best + 1e-9:
                best, best_h = v, h
        if best_h < 0:
            break
        sel[best_h] = ~sel[best_h]
        cur = best
        if sel[best_h]:
            order.append(best_h)
        else:
            order.remove(best_h)
        if caps is not None:
            taken[groups[best_h]] += 1 if sel[best_h] else -1
    return order, cur


def same_object_conflicts(terms: GlobalTerms, groups: list[int], max_overlap: float) -> np.ndarray:
    """(H, H) bool: candidates of the same group (a model, or a family of look-alikes) whose explained scene points
    overlap by more than ``max_overlap`` of the smaller set."""
    H = len(groups)
    out = np.zeros((H, H), bool)
    for a in range(H):
        for b in range(a + 1, H):
            if groups[a] != groups[b]:
                continue
            ea, eb = terms.explained[a], terms.explained[b]
            small = min(len(ea), len(eb))
            if small and len(np.intersect1d(ea, eb, assume_unique=True)) > max_overlap * small:
                out[a, b] = out[b, a] = True
    return out
