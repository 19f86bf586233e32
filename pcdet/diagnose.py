"""Where each ground-truth instance of a BOP dataset is found or lost, stage by stage.

For every instance: how many scene keypoints lie on it (within 1.5 voxel of the model placed at the true pose),
how many of those have a correct candidate match (a model keypoint that the true pose puts within the
grouping's inlier distance) and how many of the matched ones took part in grouping (``grouping.max_keypoints``
bounds the keypoints a model groups), and how those fall into the scene's clusters (grouping pairs keypoints
within one cluster only, so an instance split by a depth jump offers each part alone); the error of the best raw
hypothesis and of the best refined one (ADD or ADD-S, in diameters); whether the best raw one was refined; where
verification ranked the best refined one among that model's refined poses; and what was kept instead, with its
score terms. Each miss is attributed to one stage:

- generation: no raw hypothesis and no refined pose within the threshold (``keypoints`` when fewer than 3
  keypoints on the instance with a correct match took part in grouping: it had nothing to work with);
- first look: a raw hypothesis was within the threshold but did not reach ICP (quick verification or the
  per-model budget dropped it);
- refinement: a raw hypothesis within the threshold reached ICP and left it outside;
- verification: a refined pose within the threshold was not kept (a wrong pose scored higher, or the checks
  refused it).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from .align import transform
from .detector import Detector, Trace
from .look_alikes import transfer
from .metrics import add, adds

STAGES = ("found", "verification", "refinement", "first look", "generation", "keypoints")


@dataclass
class InstanceDiagnosis:
    """One ground-truth instance (errors in diameters; -1 where there was nothing to measure)."""

    scene_id: int
    im_id: int
    obj_id: int
    visib_fract: float | None
    scene_keypoints: int
    keypoints_on: int
    keypoints_matched: int
    keypoints_grouped: int
    raw_hypotheses: int
    best_raw: float
    best_raw_refined: bool
    best_refined: float
    rank: int
    kept_error: float
    kept_score: float
    kept_terms: dict = field(default_factory=dict)
    best_terms: dict = field(default_factory=dict)
    stage: str = ""
    seconds: float = 0.0
    grouped_clusters: list = field(default_factory=list)


def _terms(v) -> dict:
    return {"score": round(v.score, 3), "supported": v.n_supported, "occluded": v.n_occluded,
            "see_through": v.n_violations, "rendered": v.n_rendered, "visible": round(v.visible_fraction, 3)}


def diagnose_frame(det: Detector, frame, gts: list[dict], targets: dict | None, *, metric: str = "add",
                   threshold: float = 0.1, scene_id: int = 0, im_id: int = 0, trace: Trace | None = None
                   ) -> list[InstanceDiagnosis]:
    """Detect in ``frame`` with a trace and diagnose each of ``gts`` ([{"obj_id", "T_cam_model",
    "visib_fract"}], camera frame) against it. ``trace``: the ``Trace`` to fill (for a caller that wants the
    poses too); a new one when None."""
    import time

    trace = Trace() if trace is None else trace
    t0 = time.perf_counter()
    det.detect(frame, targets, trace=trace)
    seconds = time.perf_counter() - t0
    err_fn = add if metric == "add" else adds
    cfg = det.config
    out = []
    scene = trace.scene
    kp = scene.points[scene.keypoints] if scene is not None and len(scene.keypoints) else np.zeros((0, 3))
    for g in gts:
        mi = det.library.index_of(g["obj_id"])
        m = det.library[mi]
        T = g["T_cam_model"]

        def err(Te):
            return err_fn(Te, T, m.points) / m.diameter

        # a look-alike's keypoint grid and matches are its representative's (posed with its box centre at the
        # member's)
        rep = det.family_of(mi).representative
        on = np.zeros(len(kp), bool)
        if len(kp):
            from scipy.spatial import cKDTree

            d, _ = cKDTree(transform(T, m.points)).query(kp, distance_upper_bound=1.5 * cfg.preprocess.voxel)
            on = np.isfinite(d)
            if rep in trace.grid:  # only the keypoints on the grid it grouped (the scene describes a union of grids)
                on &= np.isin(np.arange(len(kp)), trace.grid[rep])
        matched = grouped = 0
        split: list[int] = []
        cands = trace.candidates.get(rep)
        if cands is not None and on.any():
            c = cands.model[on]
            T_rep = T if rep == mi else transfer(T, det.models[mi].reference, det.models[rep].reference)
            posed = transform(T_rep, det.library[rep].kp_points[np.maximum(c, 0).reshape(-1)]).reshape(*c.shape, 3)
            ok = (c >= 0) & (np.linalg.norm(posed - kp[on][:, None], axis=2) < cfg.grouping.inlier_distance)
            has = ok.any(axis=1)
            matched = int(has.sum())
            took = np.flatnonzero(on)[has]
            took = took[np.isin(took, trace.grouped.get(rep, []))]
            grouped = len(took)
            # grouping pairs keypoints within one scene cluster only: an instance split between clusters (a
            # self-occlusion's depth jump, an occluder in front) offers each part alone
            labels = scene.labels[scene.keypoints[took]]
            split = sorted(np.unique(labels, return_counts=True)[1].tolist(), reverse=True)
        raw = [(j, err(h.T_scene_model)) for j, h in enumerate(trace.hypotheses) if h.model_index == mi]
        best_raw_j, best_raw = min(raw, key=lambda x: x[1]) if raw else (-1, -1.0)
        refined = [(r, err(trace.registrations[r].T_target_source)) for r, j in enumerate(trace.refined)
                   if trace.hypotheses[j].model_index == mi] if trace.registrations else []
        best_r, best_refined = min(refined, key=lambda x: x[1]) if refined else (-1, -1.0)
        rank = -1
        if best_r >= 0:
            scores = sorted((trace.verifications[r].score for r, _ in refined), reverse=True)
            rank = scores.index(trace.verifications[best_r].score) + 1
        kept = [r for r in trace.kept if trace.hypotheses[trace.refined[r]].model_index == mi]
        kept_err = min((err(trace.registrations[r].T_target_source) for r in kept), default=-1.0)
        first_kept = kept[0] if kept else -1
        found = 0 <= kept_err < threshold
        if found:
            stage = "found"
        elif 0 <= best_refined < threshold:
            stage = "verification"
        elif 0 <= best_raw < threshold:
            stage = "refinement" if best_raw_j in trace.refined else "first look"
        else:
            stage = "generation" if grouped >= 3 else "keypoints"
        out.append(InstanceDiagnosis(
            scene_id, im_id, g["obj_id"], g.get("visib_fract"), int(len(kp)), int(on.sum()), matched, grouped,
            len(raw),
            round(float(best_raw), 3), best_raw_j in trace.refined, round(float(best_refined), 3), rank,
            round(float(kept_err), 3),
            round(float(trace.verifications[first_kept].score), 3) if first_kept >= 0 else -1.0,
            _terms(trace.verifications[first_kept]) if first_kept >= 0 else {},
            _terms(trace.verifications[best_r]) if best_r >= 0 else {}, stage, round(seconds, 3), split))
    return out


@dataclass
class Diagnosis:
    """Every instance's diagnosis and the count per stage."""

    instances: list[InstanceDiagnosis]

    @property
    def stages(self) -> dict[str, int]:
        """How many instances each stage found or lost."""
        return {s: sum(i.stage == s for i in self.instances) for s in STAGES}

    def to_dict(self) -> dict:
        """The stage counts and every instance's diagnosis, as ``pcdet diagnose --json`` writes them."""
        return {"stages": self.stages, "instances": [asdict(i) for i in self.instances]}


def diagnose(rec, det: Detector, *, targets: bool = True, metric: str = "add", threshold: float = 0.1,
             frames: list | None = None, on_frame=None) -> Diagnosis:
    """Diagnose every scored instance of every frame of ``rec`` (a BOP dataset: ``scored_gt``); ``targets`` gives
    the detector the objects present (BOP localisation); ``frames`` restricts to some frame refs."""
    out = []
    for ref in (frames if frames is not None else list(rec)):
        gts = rec.scored_gt(ref)
        res = diagnose_frame(det, rec.frame(ref), gts, rec.targets(ref) if targets else None, metric=metric,
                             threshold=threshold, scene_id=ref.scene_id, im_id=ref.im_id)
        out += res
        if on_frame:
            on_frame(ref, res)
    return Diagnosis(out)
