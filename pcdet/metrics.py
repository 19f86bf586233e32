"""Pose-error functions and BOP-style scoring. Every metric is a pure function.

Notation: model points X (N, 3) in metres, estimated pose (R_e, t_e), ground truth (R_g, t_g), both
``T_cam_model``. Definitions follow Hodan et al., "On Evaluation of 6D Object Pose Estimation" (ECCVW 2016)
and the BOP challenge (2019-2023).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .align import transform

MSSD_THRESHOLDS = np.arange(0.05, 0.51, 0.05)  # x object diameter
MSPD_THRESHOLDS_PX = np.arange(5, 51, 5)  # x image width / 640
VSD_TAUS = np.arange(0.05, 0.51, 0.05)  # x object diameter
VSD_THETAS = np.arange(0.05, 0.51, 0.05)  # error below which a pose counts as correct
VSD_DELTA = 0.015  # m, tolerance of the visibility test (BOP: 15 mm)


def add(T_est: np.ndarray, T_gt: np.ndarray, points: np.ndarray) -> float:
    """ADD (Hinterstoisser 2012): mean over model points x of ||T_est x - T_gt x|| (m)."""
    return float(np.linalg.norm(transform(T_est, points) - transform(T_gt, points), axis=1).mean())


def adds(T_est: np.ndarray, T_gt: np.ndarray, points: np.ndarray) -> float:
    """ADD-S: mean over model points x of min over y of ||T_est x - T_gt y|| (m); for symmetric objects."""
    d, _ = cKDTree(transform(T_gt, points)).query(transform(T_est, points))
    return float(d.mean())


def mssd(T_est: np.ndarray, T_gt: np.ndarray, points: np.ndarray, symmetries: list[np.ndarray] | None = None) -> float:
    """MSSD (BOP): min over symmetry transforms S of max over x of ||T_est x - T_gt S x|| (m).
    ``symmetries`` are (4, 4) model-frame transforms; the identity is always included."""
    syms = [np.eye(4)] + list(symmetries or [])
    pe = transform(T_est, points)
    return float(min(np.linalg.norm(pe - transform(T_gt @ S, points), axis=1).max() for S in syms))


def mspd(T_est: np.ndarray, T_gt: np.ndarray, points: np.ndarray, K: np.ndarray,
         symmetries: list[np.ndarray] | None = None) -> float:
    """MSPD (BOP): min over symmetries of max over x of ||proj(T_est x) - proj(T_gt S x)|| (pixels), with the
    pinhole projection by K (3, 3)."""
    def proj(T):
        p = transform(T, points) @ K.T
        return p[:, :2] / p[:, 2:3]

    syms = [np.eye(4)] + list(symmetries or [])
    pe = proj(T_est)
    return float(min(np.linalg.norm(pe - proj(T_gt @ S), axis=1).max() for S in syms))


def visibility_mask(depth_test: np.ndarray, depth_model: np.ndarray, delta: float) -> np.ndarray:
    """Pixels where the rendered model is visible in the test image (BOP'19 rule): the model is rendered there
    and it is not behind the measured surface by more than ``delta`` (m), or the measurement is missing."""
    rendered = depth_model > 0
    return rendered & ((depth_model <= depth_test + delta) | (depth_test <= 0))


def vsd(depth_est: np.ndarray, depth_gt: np.ndarray, depth_test: np.ndarray, taus, delta: float = VSD_DELTA
        ) -> np.ndarray:
    """Visible Surface Discrepancy (Hodan et al. 2016, BOP'19 visibility), one error per misalignment tolerance.

    depth_est, depth_gt : (H, W) depth (m) of the model rendered at the estimated and true pose, 0 off it.
    depth_test : (H, W) measured depth (m), 0 where missing.
    taus : misalignment tolerances (m).
    Over the union U of the visible masks V_est and V_gt (V_est also takes the pixels of V_gt that the
    estimate covers), a pixel costs 0 if it is in both and |d_est - d_gt| < tau, else 1;
    e_VSD = sum of costs / |U| (0 when U is empty and both renderings are empty, 1 otherwise).
    Depth here is z, not the distance along the ray that BOP uses; the two differ by < 1 % off-axis on VGA.
    """
    v_gt = visibility_mask(depth_test, depth_gt, delta)
    v_est = visibility_mask(depth_test, depth_est, delta) | (v_gt & (depth_est > 0))
    union = v_gt | v_est
    n = int(union.sum())
    taus = np.atleast_1d(np.asarray(taus, float))
    if n == 0:
        return np.zeros(len(taus)) if not (depth_est > 0).any() and not (depth_gt > 0).any() else np.ones(len(taus))
    both = v_gt & v_est
    diff = np.abs(depth_est[both] - depth_gt[both])
    return np.array([1.0 - float((diff < t).sum()) / n for t in taus])


def rotation_error_deg(R_est: np.ndarray, R_gt: np.ndarray) -> float:
    """Angle (degrees) of R_est R_gt^T."""
    c = (np.trace(R_est[:3, :3] @ R_gt[:3, :3].T) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


@dataclass
class InstanceErrors:
    """Errors of the estimate matched to one ground-truth instance (None where no estimate matched)."""

    scene_id: int
    im_id: int
    obj_id: int
    visib_fract: float | None
    score: float | None
    add: float | None
    adds: float | None
    mssd: float | None
    mspd: float | None
    vsd: list[float] | None = None  # one error per tau in VSD_TAUS, when depth rendering was available
    gt_index: int = -1  # position of the ground-truth entry in the image's list
    est_index: int = -1  # position of the matched estimate in the image's list (-1: none)


def match_image(gts: list[dict], ests: list[dict], points: dict[int, np.ndarray], K: np.ndarray, *,
                image_width: int = 640, symmetries: dict[int, list[np.ndarray]] | None = None,
                scene_id: int = 0, im_id: int = 0, diameters: dict[int, float] | None = None
                ) -> tuple[list[InstanceErrors], int]:
    """Match estimates to ground-truth instances of one image, per object, greedily by score (BOP style:
    each estimate, best score first, takes the unmatched instance with the lowest MSSD if that MSSD is within
    the loosest MSSD threshold).

    gts : [{"obj_id", "T_cam_model", "visib_fract"}]; ests : [{"obj_id", "score", "T_cam_model"}];
    points : {obj_id: (N, 3) model points, m}; diameters : {obj_id: m}, computed from the points when absent.
    Returns the per-instance errors and the number of estimates that matched no instance (false positives).
    """
    from .cloud import diameter

    symmetries = symmetries or {}
    diameters = dict(diameters or {})
    out: list[InstanceErrors] = []
    false_pos = 0
    for oid in sorted({g["obj_id"] for g in gts} | {e["obj_id"] for e in ests}):
        g_idx = [i for i, g in enumerate(gts) if g["obj_id"] == oid]
        g_o = [gts[i] for i in g_idx]
        e_idx = sorted([i for i, e in enumerate(ests) if e["obj_id"] == oid], key=lambda i: (-ests[i]["score"], i))
        e_o = [ests[i] for i in e_idx]
        if oid not in points:
            false_pos += len(e_o)
            continue
        X = points[oid]
        if oid not in diameters:
            diameters[oid] = diameter(X)
        diam = diameters[oid]
        taken: dict[int, int] = {}
        for ei, e in zip(e_idx, e_o):
            best, best_err = None, None
            for gi, g in enumerate(g_o):
                if gi in taken:
                    continue
                err = mssd(e["T_cam_model"], g["T_cam_model"], X, symmetries.get(oid))
                if best_err is None or err < best_err:
                    best, best_err = gi, err
            if best is not None and best_err <= MSSD_THRESHOLDS[-1] * diam:
                taken[best] = ei
            else:
                false_pos += 1
        for gi, g in enumerate(g_o):
            ei = taken.get(gi)
            if ei is None:
                out.append(InstanceErrors(scene_id, im_id, oid, g.get("visib_fract"), None, None, None, None, None,
                                          gt_index=g_idx[gi]))
                continue
            e = ests[ei]
            Te, Tg = e["T_cam_model"], g["T_cam_model"]
            out.append(InstanceErrors(scene_id, im_id, oid, g.get("visib_fract"), e["score"], add(Te, Tg, X),
                                      adds(Te, Tg, X), mssd(Te, Tg, X, symmetries.get(oid)),
                                      mspd(Te, Tg, X, K, symmetries.get(oid)), gt_index=g_idx[gi], est_index=ei))
    return out, false_pos


def summarize(errors: list[InstanceErrors], diameters: dict[int, float], false_pos: int,
              image_width: int = 640, add_threshold: float = 0.1) -> dict:
    """Recall and BOP average recall over a set of matched instances.

    recall_add / recall_adds: share of instances with ADD / ADD-S < ``add_threshold`` x diameter.
    ar_mssd: mean over MSSD thresholds 0.05..0.5 x diameter of the recall; ar_mspd: mean over 5..50 px
    (scaled by image_width / 640); ar_vsd: mean over tau 0.05..0.5 x diameter and theta 0.05..0.5, when VSD
    errors are present; ar: mean of those available (BOP's AR when all three are).
    precision_adds: estimates within the ADD-S threshold over all estimates (matched + false positives).
    """
    n = len(errors)
    if n == 0:
        return {"instances": 0}

    def share(vals):
        return float(np.mean(vals)) if vals else 0.0

    ok_add = [e.add is not None and e.add < add_threshold * diameters[e.obj_id] for e in errors]
    ok_adds = [e.adds is not None and e.adds < add_threshold * diameters[e.obj_id] for e in errors]
    ar_mssd = np.mean([share([e.mssd is not None and e.mssd < t * diameters[e.obj_id] for e in errors])
                       for t in MSSD_THRESHOLDS])
    ar_mspd = np.mean([share([e.mspd is not None and e.mspd < t * image_width / 640 for e in errors])
                       for t in MSPD_THRESHOLDS_PX])
    n_est = sum(e.score is not None for e in errors) + false_pos
    out = {"instances": n, "estimates": n_est, "recall_add": share(ok_add), "recall_adds": share(ok_adds),
           "precision_adds": (sum(ok_adds) / n_est) if n_est else 0.0,
           "ar_mssd": float(ar_mssd), "ar_mspd": float(ar_mspd)}
    parts = [ar_mssd, ar_mspd]
    if any(e.vsd is not None for e in errors):
        ar_vsd = float(np.mean([share([e.vsd is not None and e.vsd[i] < th for e in errors])
                                for i in range(len(VSD_TAUS)) for th in VSD_THETAS]))
        out["ar_vsd"] = ar_vsd
        parts.append(ar_vsd)
    out["ar"] = float(np.mean(parts))
    return out
