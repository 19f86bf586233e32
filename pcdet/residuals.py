"""Residuals of correspondences under many poses at once, the inner loop of the correspondence groupers' refits:
the distances (``pose_distances``), the correspondences within a radius of each pose (``within``), and one
Tukey-weighted Kabsch step of each pose (``tukey_step``).

Shapes: T (B, 4, 4) poses (model to scene); cm, cs (M, 3) model and scene points of M correspondences (m). The
residual of correspondence m under pose b is ``|R_b cm_m + t_b - cs_m|``.

``within`` and ``tukey_step`` run a small compiled kernel (``pcdet/_residuals.c``, built by ``setup.py`` where a C
compiler is at hand) and otherwise numpy. The two sum in different orders, so a residual can differ in the last bit
(a set only where it lies that close to the radius) and a step's pose by up to about 1e-12 (m, and per rotation
entry; ``tests/test_residuals.py``).
"""
from __future__ import annotations

import numpy as np

from .align import kabsch_from_sums, kabsch_shared

try:  # the compiled kernel, where the install could build it
    from . import _residuals
except ImportError:  # pragma: no cover - exercised where no compiler was at hand
    _residuals = None


def compiled() -> bool:
    """Whether the compiled kernel is in use (otherwise numpy computes the same results)."""
    return _residuals is not None


def _f64(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def pose_distances(T: np.ndarray, cm: np.ndarray, cs: np.ndarray) -> np.ndarray:
    """(B, M) residuals (m) of the correspondences cm -> cs under each pose T. One product per coordinate keeps
    every array (B, M) and contiguous."""
    mh = np.vstack([cm.T, np.ones(len(cm))])  # (4, M) homogeneous model points
    e = T[:, 0, :] @ mh - cs[:, 0]
    d2 = e * e
    for i in (1, 2):
        e = T[:, i, :] @ mh - cs[:, i]
        d2 += e * e
    return np.sqrt(d2)


def _in_reach(T: np.ndarray, cm: np.ndarray, cs: np.ndarray, r: float) -> list[np.ndarray] | None:
    """For each pose T, the indices (ascending) of the correspondences that can lie within ``r`` of it: those
    whose scene point is within r of the ball that holds every placed model point (|T cm - cs| < r needs
    |cs - T c| < R + r, with R the model points' largest distance from their centre c). None when there are few
    correspondences or a third or more are in reach of an average pose: then measuring them all at once is cheaper
    than one pose at a time.

    The balls are tested on the distinct scene points only: a scene keypoint's candidates are consecutive rows
    of cs (as ``grouping.common.correspondence_points`` lays them out), so each run of equal rows is one point."""
    if len(cm) < 4000:
        return None
    c = (cm.min(axis=0) + cm.max(axis=0)) / 2
    reach = np.sqrt(np.max(np.einsum("ij,ij->i", cm - c, cm - c))) + r + 1e-6  # a micrometre to spare
    new = np.r_[True, np.any(cs[1:] != cs[:-1], axis=1)]
    U, owner = cs[new], np.cumsum(new) - 1
    centres = np.einsum("bij,j->bi", T[:, :3, :3], c) + T[:, :3, 3]
    d2 = np.zeros((len(T), len(U)))
    for i in range(3):
        d2 += (U[None, :, i] - centres[:, None, i]) ** 2
    inside = d2 < reach * reach
    if inside.mean() > 1 / 3:
        return None
    return [np.flatnonzero(row[owner]) for row in inside]


def within(T: np.ndarray, cm: np.ndarray, cs: np.ndarray, r: float, *, use_compiled: bool = True
           ) -> list[np.ndarray]:
    """For each pose T (B, 4, 4), the indices (ascending, int64) of the correspondences whose residual is under
    ``r`` (m). ``use_compiled`` False takes numpy even where the kernel is built (the tests compare the two)."""
    if use_compiled and _residuals is not None:
        B = len(T)
        out = np.frombuffer(_residuals.within(_f64(T), _f64(cm), _f64(cs), float(r)), np.int64)
        return np.split(out[B:], np.cumsum(out[:B])[:-1]) if B else []
    reach = _in_reach(T, cm, cs, r)
    if reach is None:
        return [np.flatnonzero(row < r) for row in pose_distances(T, cm, cs)]
    return [idx[pose_distances(T[b:b + 1], cm[idx], cs[idx])[0] < r] for b, idx in enumerate(reach)]


def tukey_step(T: np.ndarray, cm: np.ndarray, cs: np.ndarray, c: float, *, use_compiled: bool = True
               ) -> tuple[np.ndarray, np.ndarray]:
    """One robust step of each pose T (B, 4, 4): Kabsch on the correspondences weighted by Tukey's biweight of
    their residual, (1 - (d / c)^2)^2 under ``c`` (m) and 0 above (plus 1e-12 each, so no weighting is empty).
    Returns ``(ok, T_new)``: ok (B,) bool, whether at least 3 residuals were under c; T_new (B, 4, 4), the
    step's pose where ok and T elsewhere."""
    T_new = np.array(T, dtype=np.float64)
    if use_compiled and _residuals is not None:
        counts, sums = np.zeros(len(T), np.int64), np.zeros((len(T), 16))
        _residuals.tukey_sums(_f64(T), _f64(cm), _f64(cs), float(c), counts, sums)
        ok = counts >= 3
        if ok.any():
            T_new[ok] = kabsch_from_sums(sums[ok])
        return ok, T_new
    d = pose_distances(T, cm, cs)
    inside = d < c
    ok = inside.sum(axis=1) >= 3
    if ok.any():
        w = np.where(inside[ok], (1 - (d[ok] / c) ** 2) ** 2, 0.0) + 1e-12
        T_new[ok] = kabsch_shared(cm, cs, w)
    return ok, T_new
