"""pcdet beside the tools people stitch together by hand, on the same synthetic suite, in one run.

Methods (each is told which objects are in the frame, as in BOP's localisation task, and returns one pose per
object instance):
  pcdet              Detector with --targets gt
  pcdet-no-targets   Detector searching all six models; its best detections of each present object are scored
  pcdet-gc, pcdet-hough   Detector with --targets gt and pipelines/gc.toml, pipelines/hough.toml
  o3d-tutorial       Open3D's tutorial recipe on the whole frame: voxel grid, normals, FPFH,
                     registration_ransac_based_on_feature_matching, point-to-plane ICP
  o3d-careful        the recipe a careful user writes: range crop, dominant plane removed, DBSCAN clusters,
                     the tutorial registration per cluster and model, best cluster per model kept
  opencv-ppf         OpenCV's PPF3DDetector (Drost et al. 2010) with its ICP, models sampled at 4 % of diameter

Scores: recall at ADD-S < 0.1 d and at ADD < 0.1 d, median seconds per frame, and the ratios to pcdet.
Run:  python scripts/bench_peers.py [--scenes 20] [--objects 4] [--seed 2026] [--only pcdet,o3d-careful]
      python scripts/bench_peers.py --data ../shared/data/linemod_cat   (real frames, the dataset's own models)
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from pcdet._o3d import o3d
from pcdet.config import load_pipeline
from pcdet.datasets.bop import BopDataset
from pcdet.detector import Detector
from pcdet.evaluate import evaluate
from pcdet.library import ModelLibrary
from pcdet.synth import SynthConfig, synthesize

ROOT = Path(__file__).resolve().parent.parent
VOXEL = 0.005  # the tutorial's choice for objects of this size


def _pcd(points, normals=None):
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, float)))
    if normals is not None:
        pc.normals = o3d.utility.Vector3dVector(np.asarray(normals, float))
    return pc


def _prep(pc, voxel):
    down = pc.voxel_down_sample(voxel)
    down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    down.orient_normals_towards_camera_location(np.zeros(3))
    fpfh = o3d.pipelines.registration.compute_fpfh_feature(
        down, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
    return down, fpfh


def _o3d_register(src, src_f, tgt, tgt_f, voxel):
    reg = o3d.pipelines.registration
    dist = 1.5 * voxel
    res = reg.registration_ransac_based_on_feature_matching(
        src, tgt, src_f, tgt_f, True, dist, reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(dist)],
        reg.RANSACConvergenceCriteria(100000, 0.999))
    icp = reg.registration_icp(src, tgt, dist, res.transformation, reg.TransformationEstimationPointToPlane())
    return icp.transformation, icp.fitness


class O3DTutorial:
    name = "o3d-tutorial"

    def __init__(self, lib):
        self.lib = lib
        self.models = {m.obj_id: _prep(_pcd(m.points, m.normals), VOXEL) for m in lib}

    def __call__(self, frame, targets):
        o3d.utility.random.seed(0)
        pts, _ = frame.points()
        scene, sf = _prep(_pcd(pts), VOXEL)
        out = []
        for oid, n in targets.items():
            src, f = self.models[oid]
            T, fit = _o3d_register(src, f, scene, sf, VOXEL)
            out += [(oid, fit, np.asarray(T))] * n
        return out


class O3DCareful(O3DTutorial):
    name = "o3d-careful"

    def __call__(self, frame, targets):
        o3d.utility.random.seed(0)
        pts, _ = frame.points()
        pts = pts[(pts[:, 2] > 0.1) & (pts[:, 2] < 2.0)]
        pc = _pcd(pts).voxel_down_sample(VOXEL / 2)
        _, inl = pc.segment_plane(0.008, 3, 500)
        objs = pc.select_by_index(inl, invert=True)
        labels = np.asarray(objs.cluster_dbscan(eps=0.012, min_points=10))
        clusters = []
        for lab in range(labels.max() + 1 if len(labels) else 0):
            c = objs.select_by_index(np.flatnonzero(labels == lab))
            if len(c.points) >= 60:
                clusters.append(_prep(c, VOXEL))
        # every (model, cluster) pair registered; clusters then go to models greedily by ICP fitness, each once
        pairs = []
        for oid in targets:
            src, f = self.models[oid]
            for ci, (c, cf) in enumerate(clusters):
                T, fit = _o3d_register(src, f, c, cf, VOXEL)
                pairs.append((fit, oid, ci, np.asarray(T)))
        pairs.sort(key=lambda x: (-x[0], x[1], x[2]))
        left, used, out = dict(targets), set(), []
        for fit, oid, ci, T in pairs:
            if left[oid] > 0 and ci not in used:
                out.append((oid, fit, T))
                left[oid] -= 1
                used.add(ci)
        return out


class OpenCVPPF:
    name = "opencv-ppf"

    def __init__(self, lib):
        import cv2

        self.cv2 = cv2
        self.det = {}
        for m in lib:
            d = cv2.ppf_match_3d_PPF3DDetector(0.04, 0.05)
            d.trainModel(np.hstack([m.points, m.normals]).astype(np.float32))
            self.det[m.obj_id] = (d, np.hstack([m.points, m.normals]).astype(np.float32))

    def __call__(self, frame, targets):
        cv2 = self.cv2
        pts, _ = frame.points()
        pc = _pcd(pts[(pts[:, 2] > 0.1) & (pts[:, 2] < 2.0)]).voxel_down_sample(VOXEL / 2)
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.01, max_nn=30))
        pc.orient_normals_towards_camera_location(np.zeros(3))
        scene = np.hstack([np.asarray(pc.points), np.asarray(pc.normals)]).astype(np.float32)
        icp = cv2.ppf_match_3d_ICP(100)
        out = []
        for oid, n in targets.items():
            d, model = self.det[oid]
            results = d.match(scene, 1.0 / 40.0, 0.05)
            results = list(results[: max(n, 5)])
            if not results:
                continue
            _, results = icp.registerModelToScene(model, scene, results)
            results = sorted(results, key=lambda r: -r.numVotes)[:n]
            out += [(oid, float(r.numVotes), np.asarray(r.pose, float)) for r in results]
        return out


class Pcdet:
    name = "pcdet"
    preset = "default"

    def __init__(self, lib):
        self.det = Detector(lib, load_pipeline(self.preset))

    def __call__(self, frame, targets):
        r = self.det.detect(frame, targets)
        return [(d.obj_id, d.score, d.T_cam_model) for d in r.detections]


class PcdetGC(Pcdet):
    name, preset = "pcdet-gc", "gc"


class PcdetHough(Pcdet):
    name, preset = "pcdet-hough", "hough"


class PcdetFree(Pcdet):
    """pcdet told nothing: all six models searched; for scoring, the best detections of each present object."""

    name = "pcdet-no-targets"

    def __call__(self, frame, targets):
        r = self.det.detect(frame)
        out = []
        for oid, n in targets.items():
            out += [(d.obj_id, d.score, d.T_cam_model) for d in r.detections if d.obj_id == oid][:n]
        return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--objects", type=int, default=4)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--data", type=Path, default=None, help="existing BOP dataset, real or synthetic, its models in "
                    "DATA/models (default: synthesise one from models/)")
    ap.add_argument("--only", default="pcdet,pcdet-no-targets,pcdet-gc,pcdet-hough,o3d-tutorial,o3d-careful,"
                    "opencv-ppf")
    args = ap.parse_args()
    lib = ModelLibrary.from_folder(args.data / "models" if args.data else ROOT / "models")
    tmp = None
    if args.data is None:
        tmp = tempfile.TemporaryDirectory()
        args.data = synthesize(lib, Path(tmp.name) / "suite",
                               SynthConfig(scenes=args.scenes, objects=args.objects, seed=args.seed))
    ds = BopDataset(args.data)
    frames = [(img, ds.frame(img), ds.targets(img)) for img in ds]
    makers = {"pcdet": Pcdet, "pcdet-no-targets": PcdetFree, "pcdet-gc": PcdetGC, "pcdet-hough": PcdetHough,
              "o3d-tutorial": O3DTutorial, "o3d-careful": O3DCareful, "opencv-ppf": OpenCVPPF}
    rows = []
    for name in args.only.split(","):
        method = makers[name](lib)
        ests, times = [], []
        for img, frame, targets in frames:
            t0 = time.perf_counter()
            found = method(frame, targets)
            times.append(time.perf_counter() - t0)
            ests += [{"scene_id": img.scene_id, "im_id": img.im_id, "obj_id": oid, "score": float(s),
                      "T_cam_model": T} for oid, s, T in found]
        ev = evaluate(ds, ests, lib).overall
        rows.append((name, ev["recall_adds"], ev["recall_add"], float(np.median(times))))
        print(f"{name:14s} recall ADD-S {ev['recall_adds']:.3f}  ADD {ev['recall_add']:.3f}  "
              f"median {np.median(times):.3f} s/frame", flush=True)
    base = next((r for r in rows if r[0] == "pcdet"), rows[0])
    n_inst = sum(sum(t.values()) for _, _, t in frames)
    source = f"seed {args.seed}" if tmp is not None else str(args.data)
    print(f"\n{len(frames)} frames, {n_inst} instances, 640x480, {len(lib)}-model library, {source}")
    print(f"| method | recall ADD-S | recall ADD | median s/frame | {base[0]} recall / method | "
          f"method time / {base[0]} |")
    print("|---|---|---|---|---|---|")
    for n, rs, ra, t in rows:
        rr = f"{base[1] / rs:.2f}x" if rs > 0 else "inf"
        print(f"| {n} | {rs:.3f} | {ra:.3f} | {t:.3f} | {rr} | {t / base[3]:.2f}x |")


if __name__ == "__main__":
    main()
