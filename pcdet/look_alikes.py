"""Look-alike models: the same shape at other sizes (a product line in several sizes, a part and its scaled
copies), found once when the detector is built.

The detector groups correspondences once per family, for its representative, and gives the representative's
best raw poses their short coarse ICP: look-alikes match the same scene keypoints and slide to the same places, so
doing either for each of them repeats the same work, and gives clutter one more chance per size to look like the
shape. Every member takes the representative's coarse poses (``transfer``) and is then refined by the full ICP
and verified on its own, which is where the size is told apart.

Two models are look-alikes when, each centred on its bounding box in its own frame and scaled to the smaller
one's size, their surface samples lie within ``distance`` of each other on average (both ways), and their
diameters differ by a factor under ``MAX_SCALE``. Models in different frames are never look-alikes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

# look-alikes further apart in size are grouped each on its own: a raw pose moved from one to the other is then
# off by more than a quarter of the radius at the surface, beyond what the coarse ICP pulls in
MAX_SCALE = 1.25
# bounding-box proportions (extent / diameter) further apart than this are not compared point by point
BOX_TOLERANCE = 0.1


@dataclass(frozen=True)
class Family:
    """Models (positions in the library) that are one shape at several sizes. ``representative`` is grouped for
    all of them; ``members`` (ascending) include it."""

    representative: int
    members: tuple[int, ...]


def look_alike_families(points: list[np.ndarray], centres: list[np.ndarray], diameters: list[float],
                        distance: float) -> list[Family]:
    """The library's models as families, in order of their first member.

    points : per model (N_i, 3) surface samples (m, model frame); centres : per model (3,) centre of its
    bounding box (m); diameters : per model (m); distance : m, the largest mean closest-point distance between
    two look-alikes at the smaller one's size (0: every model is its own family).

    The representative of a family is the model with the most look-alikes not yet in a family, ties broken by
    the size nearest the middle of its look-alikes' sizes, then by library order; it takes all of those
    look-alikes, and the rest form families the same way. So every member is within ``MAX_SCALE`` of its
    representative in size, whichever order the library lists the models in."""
    n = len(points)
    near = [set() for _ in range(n)]
    if distance > 0:
        unit = [(np.asarray(p, np.float64) - c) / d for p, c, d in zip(points, centres, diameters)]
        box = [np.ptp(u, axis=0) for u in unit]
        trees = [cKDTree(u) for u in unit]
        for i in range(n):
            for j in range(i + 1, n):
                small, big = sorted((diameters[i], diameters[j]))
                if small <= 0 or big / small >= MAX_SCALE or np.abs(box[i] - box[j]).max() > BOX_TOLERANCE:
                    continue
                # both ways, at the smaller model's size
                d = max(trees[j].query(unit[i])[0].mean(), trees[i].query(unit[j])[0].mean()) * small
                if d <= distance:
                    near[i].add(j)
                    near[j].add(i)
    def rank(i: int, left: set[int]) -> tuple:
        group = [i, *(near[i] & left)]
        middle = np.mean(np.log([diameters[g] for g in group]))
        return -len(group), abs(np.log(diameters[i]) - middle), i

    left = set(range(n))
    out = []
    while left:
        rep = min(left, key=lambda i: rank(i, left))
        members = tuple(sorted({rep, *(near[rep] & left)}))
        out.append(Family(rep, members))
        left -= set(members)
    return sorted(out, key=lambda f: f.members[0])


def transfer(T_scene_rep: np.ndarray, rep_centre: np.ndarray, member_centre: np.ndarray) -> np.ndarray:
    """(4, 4) pose of a look-alike from its representative's ``T_scene_rep`` (4, 4): the same rotation, with
    the member's bounding-box centre (3,) where the representative's (3,) was (both in their own frames, m)."""
    T = np.array(T_scene_rep, dtype=np.float64)
    T[:3, 3] = T_scene_rep[:3, 3] + T_scene_rep[:3, :3] @ (np.asarray(rep_centre) - np.asarray(member_centre))
    return T
