"""Correspondence grouping under outliers: the share of trials in which each grouper recovers the pose
(rotation error < 2 degrees, translation error < 1 cm), and its median time per trial.

Synthetic sets: 1000 keypoints of a shipped model (with their view normals) under a random pose and 1 mm
noise; a chosen share of them is matched to a random model keypoint instead of its own. Real sets: the six
TEASER++ benchmark cases in ../shared/data/teaser_cases (no normals: the angle tests pass trivially; the scale
is divided out, as their SOURCE.txt suggests, for a rigid problem).

Hough needs local reference frames: in the synthetic sets the scene keypoints carry the model keypoints'
frames rotated by the true pose (so LRF noise is not part of this benchmark); the TEASER cases have no
surfaces, so Hough is not run on them.

Run: python scripts/bench_grouping.py [--trials 30] [--n 1000]
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from pcdet.config import PipelineConfig
from pcdet.grouping import make_grouper
from pcdet.io.clouds import read_cloud
from pcdet.library import ModelLibrary
from pcdet.matching import Candidates
from pcdet.metrics import rotation_error_deg
from pcdet.model import ObjectModel
from pcdet.prepared_model import PreparedModel
from pcdet.scene import SceneKeypoints

ROOT = Path(__file__).resolve().parent.parent


def run(method, S, N, cand, dist, model, cfg, seed, lrf=None):
    """One call of the registered grouper ``method`` on scene keypoints S, N (n, 3) with their candidates."""
    grouper = make_grouper(dataclasses.replace(cfg, method=method))
    return grouper.group(SceneKeypoints(S, N, lrfs=lrf), model, Candidates(cand, dist), np.random.default_rng(seed))


def ok(hyps, T):
    if not hyps:
        return False
    E = hyps[0].T_scene_model
    return rotation_error_deg(E[:3, :3], T[:3, :3]) < 2 and np.linalg.norm(E[:3, 3] - T[:3, 3]) < 0.01


def synthetic(trials, methods, n=1000, lrf_noise_deg=5.0):
    m = ModelLibrary.from_folder(ROOT / "models")[0]
    pm = PreparedModel.build(m, 0, icp_spacing=0.008)
    cfg = PipelineConfig().grouping
    good = np.flatnonzero(~np.isnan(m.kp_lrfs[:, 0, 0]))
    print(f"\n{n} correspondences per trial, {trials} trials, 1 mm point noise, scene LRFs turned by "
          f"{lrf_noise_deg:g} deg (standard deviation)")
    print("| outliers | " + " | ".join(f"{x} success | {x} median ms" for x in methods) + " |")
    print("|---|" + "---|---|" * len(methods))
    for share in (0.5, 0.9, 0.95, 0.99):
        res = {x: [0, []] for x in methods}
        rng = np.random.default_rng(0)
        for t in range(trials):
            idx = rng.choice(good, n, replace=n > len(good))
            T = np.eye(4)
            T[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
            T[:3, 3] = rng.normal(0, 0.1, 3) + [0, 0, 0.8]
            S = m.kp_points[idx] @ T[:3, :3].T + T[:3, 3] + rng.normal(0, 0.001, (n, 3))
            N = m.kp_normals[idx] @ T[:3, :3].T
            F = m.kp_lrfs[idx] @ T[:3, :3].T  # the scene keypoints' LRFs: the model's, rotated ...
            # ... and perturbed: a random axis, an angle with standard deviation lrf_noise_deg
            axis = rng.normal(size=(n, 3))
            axis /= np.linalg.norm(axis, axis=1, keepdims=True)
            jitter = Rotation.from_rotvec(axis * np.radians(lrf_noise_deg) * rng.normal(size=(n, 1))).as_matrix()
            F = F @ np.transpose(jitter, (0, 2, 1))
            cand = idx.copy()
            bad = rng.random(n) < share
            cand[bad] = rng.choice(good, bad.sum())
            dist = rng.random((n, 1))  # descriptor distance carries no information here
            for x in methods:
                t0 = time.perf_counter()
                h = run(x, S, N, cand[:, None], dist, pm, cfg, t, F)
                res[x][1].append(time.perf_counter() - t0)
                res[x][0] += ok(h, T)
        print(f"| {share:.0%} | " + " | ".join(f"{res[x][0] / trials:.2f} | {np.median(res[x][1]) * 1000:.0f}"
                                              for x in methods) + " |", flush=True)


def teaser(methods):
    base = ROOT.parent / "shared" / "data" / "teaser_cases"
    if not base.is_dir():
        print("teaser_cases absent")
        return
    print("\n| TEASER case | outliers | " + " | ".join(f"{x} rot err (deg) | {x} ms" for x in methods) + " |")
    print("|---|---|" + "---|---|" * len(methods))
    for d in sorted(base.glob("benchmark_*")):
        src, dst = read_cloud(d / "src.ply").points, read_cloud(d / "dst.ply").points
        R = np.loadtxt(d / "R_ref.csv", delimiter=",")
        t = np.loadtxt(d / "t_ref.csv", delimiter=",").reshape(3)
        s = float(np.loadtxt(d / "s_ref.csv", delimiter=",").reshape(-1)[0])
        S = dst / s
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, t / s
        inl = np.linalg.norm(S - (src @ R.T + T[:3, 3]), axis=1) < 0.05
        diam = float(np.ptp(src, axis=0).max() * 1.8)
        zeros = np.zeros_like(src)
        loose = {"edge_tolerance": 0.05, "normal_tolerance_deg": 180.0}  # no normals: lengths only
        cfg = PipelineConfig().replace(grouping={"inlier_distance": 0.05, "min_inliers": 3,
                                                 "ransac": {**loose, "iterations": 5000}, "gc": loose}).grouping
        nan = np.full((len(src), 3, 3), np.nan)
        model = ObjectModel(d.name, 0, str(d), src, zeros, src, zeros, np.zeros((len(src), 33), np.float32), nan,
                            diam)
        pm = PreparedModel(model, 0, src, zeros, src.mean(axis=0), cKDTree(model.features))
        cells = []
        for x in methods:
            t0 = time.perf_counter()
            h = run(x, S, zeros, np.arange(len(src))[:, None], np.zeros((len(src), 1)), pm, cfg, 0)
            dt = time.perf_counter() - t0
            err = rotation_error_deg(h[0].T_scene_model[:3, :3], R) if h else float("nan")
            cells.append(f"{err:.2f} | {dt * 1000:.0f}")
        print(f"| {d.name} ({len(src)} pairs) | {1 - inl.mean():.0%} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=30)
    ap.add_argument("--methods", default="ransac,gc,hough")
    ap.add_argument("--n", type=int, default=1000, help="correspondences per synthetic trial")
    ap.add_argument("--lrf-noise-deg", type=float, default=5.0, help="scene LRF perturbation (Hough only)")
    a = ap.parse_args()
    synthetic(a.trials, a.methods.split(","), a.n, a.lrf_noise_deg)
    teaser([x for x in a.methods.split(",") if x != "hough"])  # no LRFs without normals
