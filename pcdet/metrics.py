"""Pose-error functions and BOP-style scoring. Every metric is a pure function.

Notation: model points X (N, 3) in metres, estimated pose (R_e, t_e), ground truth (R_g, t_g), both
``T_cam_model``. Definitions follow Hodan et al., "On Evaluation of 6D Object Pose Estimation" (ECCVW 2016)
and the BOP challenge (2019-2023).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from .align import transform

MSSD_THRESHOLDS = np.arange(0.05, 0.51, 0.05)  # x object diameter
MSPD_THRESHOLDS_PX = np.arange(5, 51, 5)  # x image width / 640
VSD_TAUS = np.arange(0.05, 0.51, 0.05)  # x object diameter
VSD_THETAS = np.arange(0.05, 0.51, 0.05)  # error below which a pose counts as correct
VSD_DELTA = 0.015  # m, tolerance of the visibility test (BOP: 15 mm)


def add(T_est: np.ndarray, T_gt: np.ndarray, points: np.ndarray, symmetries: list[np.ndarray] | None = None) -> float:
    """ADD (Hinterstoisser 2012): mean over model points x of ||T_est x - T_gt x|| (m). With ``symmetries``
    ((4, 4) model-frame transforms, as for MSSD) the least over them of ||T_est x - T_gt S x||, so that a pose
    turned by one of the object's declared symmetries is as right as the annotated one."""
    pe = transform(T_est, points)
    syms = [np.eye(4)] + list(symmetries or [])
    return float(min(np.linalg.norm(pe - transform(T_gt @ S, points), axis=1).mean() for S in syms))


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


def symmetry_transforms(info: dict, max_step: float = 0.01) -> list[np.ndarray]:
    """An object's symmetries from its BOP ``models_info.json`` entry (lengths in mm there), as (4, 4)
    model-frame transforms in metres, the identity first. ``symmetries_discrete`` are listed 4 x 4 matrices
    (row-major); each ``symmetries_continuous`` {"axis", "offset"} is sampled as rotations about the axis
    through the offset, so finely that no point within the model's diameter moves more than ``max_step`` x
    the diameter between samples (BOP's rule: ceil(pi / max_step) samples). Discrete and continuous ones are
    combined."""
    disc = [np.eye(4)]
    for m in info.get("symmetries_discrete", []) or []:
        T = np.asarray(m, float).reshape(4, 4).copy()
        T[:3, 3] /= 1000.0
        disc.append(T)
    cont = [np.eye(4)]
    for c in info.get("symmetries_continuous", []) or []:
        axis = np.asarray(c["axis"], float)
        axis /= np.linalg.norm(axis)
        offset = np.asarray(c.get("offset", [0, 0, 0]), float) / 1000.0
        n = int(np.ceil(np.pi / max_step))
        for i in range(1, n):
            from scipy.spatial.transform import Rotation

            R = Rotation.from_rotvec(axis * 2 * np.pi * i / n).as_matrix()
            T = np.eye(4)
            T[:3, :3] = R
            T[:3, 3] = offset - R @ offset
            cont.append(T)
    return [d @ c for c in cont for d in disc]


@dataclass
class ObjectErrors:
    """The pose errors between the estimates and the ground-truth instances of one object in one image.

    scores : (E,) estimate scores; visib_fract : (G,) visible fraction of each instance (None when unknown);
    errors : {"add", "adds", "mssd" (m), "mspd" (px)} -> (E, G), and "vsd" -> (E, G, len(VSD_TAUS)) when
    depth was rendered; diameter : m; lines : (E,) where each estimate came from (file line), for messages.
    """

    scene_id: int
    im_id: int
    obj_id: int
    diameter: float
    scores: np.ndarray
    visib_fract: list
    errors: dict[str, np.ndarray]
    lines: list = field(default_factory=list)


def object_errors(gts: list[dict], ests: list[dict], points: np.ndarray, K: np.ndarray, diameter: float, *,
                  symmetries: list[np.ndarray] | None = None, scene_id: int = 0, im_id: int = 0,
                  obj_id: int = 0) -> ObjectErrors:
    """ADD, ADD-S, MSSD and MSPD of every estimate against every ground-truth instance of one object.

    gts : [{"T_cam_model", "visib_fract"}]; ests : [{"score", "T_cam_model"}]; points : (N, 3) model points (m);
    symmetries : the object's model-frame symmetries (``symmetry_transforms``), for ADD, MSSD and MSPD."""
    E, G = len(ests), len(gts)
    errs = {k: np.full((E, G), np.inf) for k in ("add", "adds", "mssd", "mspd")}
    for i, e in enumerate(ests):
        for j, g in enumerate(gts):
            Te, Tg = e["T_cam_model"], g["T_cam_model"]
            errs["add"][i, j] = add(Te, Tg, points, symmetries)
            errs["adds"][i, j] = adds(Te, Tg, points)
            errs["mssd"][i, j] = mssd(Te, Tg, points, symmetries)
            errs["mspd"][i, j] = mspd(Te, Tg, points, K, symmetries)
    return ObjectErrors(scene_id, im_id, obj_id, diameter, np.array([e["score"] for e in ests], float),
                        [g.get("visib_fract") for g in gts], errs, [e.get("line") for e in ests])


def match(errors: np.ndarray, scores: np.ndarray, threshold: float) -> list[tuple[int, int]]:
    """BOP's matching of estimates to instances under one error and one threshold: estimates in order of
    decreasing score (ties: lower index first) each take the unmatched instance with the lowest error, if that
    error is below ``threshold``. errors : (E, G). Returns the (estimate, instance) pairs."""
    taken: set[int] = set()
    pairs = []
    for i in sorted(range(len(scores)), key=lambda i: (-scores[i], i)):
        row = [(errors[i, j], j) for j in range(errors.shape[1]) if j not in taken and errors[i, j] < threshold]
        if row:
            j = min(row)[1]
            taken.add(j)
            pairs.append((i, j))
    return pairs


def summarize(objects: list[ObjectErrors], image_width: int = 640, add_threshold: float = 0.1) -> dict:
    """Recalls and BOP average recalls over the per-object, per-image errors ``objects``.

    Every metric matches estimates to instances on its own (``match``, per threshold), as the BOP toolkit does,
    so each column means what its name says:
    recall_add / recall_adds : instances matched at ADD (up to the declared symmetries) / ADD-S <
      ``add_threshold`` x diameter, over all
      instances; precision_adds : estimates matched at that ADD-S threshold, over all estimates.
    ar_mssd : mean over thresholds 0.05..0.5 x diameter of the MSSD recall; ar_mspd : mean over 5..50 px
      (x image_width / 640); ar_vsd : mean over tau 0.05..0.5 x diameter and theta 0.05..0.5, when VSD errors
      are present; ar : mean of those available (BOP's AR when all three are).
    """
    n = sum(len(o.visib_fract) for o in objects)
    n_est = sum(len(o.scores) for o in objects)
    if n == 0:
        return {"instances": 0, "estimates": n_est}

    def recall(key, th_of, idx=None):
        hits = 0
        for o in objects:
            if len(o.scores) and len(o.visib_fract):
                e = o.errors[key] if idx is None else o.errors[key][..., idx]
                hits += len(match(e, o.scores, th_of(o)))
        return hits / n

    out = {"instances": n, "estimates": n_est,
           "recall_add": recall("add", lambda o: add_threshold * o.diameter),
           "recall_adds": recall("adds", lambda o: add_threshold * o.diameter)}
    out["precision_adds"] = out["recall_adds"] * n / n_est if n_est else 0.0
    out["ar_mssd"] = float(np.mean([recall("mssd", lambda o, t=t: t * o.diameter) for t in MSSD_THRESHOLDS]))
    out["ar_mspd"] = float(np.mean([recall("mspd", lambda o, t=t: t * image_width / 640)
                                    for t in MSPD_THRESHOLDS_PX]))
    parts = [out["ar_mssd"], out["ar_mspd"]]
    if objects and all("vsd" in o.errors for o in objects):
        out["ar_vsd"] = float(np.mean([recall("vsd", lambda o, th=th: th, idx=i)
                                       for i in range(len(VSD_TAUS)) for th in VSD_THETAS]))
        parts.append(out["ar_vsd"])
    out["ar"] = float(np.mean(parts))
    return out
