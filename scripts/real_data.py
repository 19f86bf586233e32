"""pcdet on the real data in ../shared/data, with the errors against each set's ground truth.

Run: python scripts/real_data.py   (prints one markdown table per data set)
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pcdet.datasets.bop import BopDataset
from pcdet.detector import Detector
from pcdet.frame import Frame
from pcdet.io.models import load_geometry
from pcdet.library import ModelLibrary
from pcdet.metrics import add, adds, rotation_error_deg
from pcdet.register import register

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def milk():
    d = DATA / "pcl_milk"
    gt = json.loads((d / "gt.json").read_text())["poses"]
    frame = Frame.from_cloud(d / "scene.pcd")
    print("| PCL milk model | detections | translation error (mm) | rotation error (deg) | seconds |")
    print("|---|---|---|---|---|")
    for name in ("model_milk.pcd", "model_milk_crop.pcd"):
        det = Detector(ModelLibrary.from_files([d / name]))
        det.detect(frame)  # warm-up: the first call pays for imports and thread start-up
        t0 = time.perf_counter()
        res = det.detect(frame)
        dt = time.perf_counter() - t0
        T_gt = np.array(gt[name])
        for x in res.detections[:1]:
            print(f"| {name} | {len(res.detections)} | {np.linalg.norm(x.T_cam_model[:3, 3] - T_gt[:3, 3]) * 1000:.2f} "
                  f"| {rotation_error_deg(x.T_cam_model[:3, :3], T_gt[:3, :3]):.2f} | {dt:.2f} |")


def ycbv():
    ds = BopDataset(DATA / "ycbv_frame")
    lib = ModelLibrary.from_folder(ds.models_dir)
    img = ds.images[0]
    frame = ds.frame(img)
    det = Detector(lib)
    print("\n| YCB-V object | ADD-S / d (targets) | ADD / d (targets) | ADD-S / d (no targets) |")
    print("|---|---|---|---|")
    r_t, r_f = det.detect(frame, ds.targets(img)), det.detect(frame)

    def best(res, fn, g, m):
        e = [fn(x.T_cam_model, g["T_cam_model"], m.points) / m.diameter for x in res.detections
             if x.obj_id == m.obj_id]
        return f"{min(e):.3f}" if e else "not found"

    for g in ds.gt(img):
        m = lib.by_id(g["obj_id"])
        print(f"| {m.name} | {best(r_t, adds, g, m)} | {best(r_t, add, g, m)} | {best(r_f, adds, g, m)} |")


def bunny():
    d = DATA / "bunny"
    X = load_geometry(d / "bun_zipper_res3.ply").vertices
    print("\n| bunny scan | mean error (mm) | largest error (mm) | rotation error (deg) | seconds |")
    print("|---|---|---|---|---|")
    for line in (d / "bun.conf").read_text().splitlines():
        w = line.split()
        if not w or w[0] != "bmesh":
            continue
        T_model_scan = np.eye(4)
        T_model_scan[:3, :3] = Rotation.from_quat([float(v) for v in w[5:9]]).as_matrix().T
        T_model_scan[:3, 3] = [float(v) for v in w[2:5]]
        T_gt = np.linalg.inv(T_model_scan)
        t0 = time.perf_counter()
        r = register(d / "bun_zipper_res3.ply", d / w[1])
        dt = time.perf_counter() - t0
        T = r.T_target_source
        e = np.linalg.norm((X @ T[:3, :3].T + T[:3, 3]) - (X @ T_gt[:3, :3].T + T_gt[:3, 3]), axis=1)
        print(f"| {w[1]} | {e.mean() * 1000:.2f} | {e.max() * 1000:.2f} | "
              f"{rotation_error_deg(T[:3, :3], T_gt[:3, :3]):.2f} | {dt:.2f} |")


if __name__ == "__main__":
    milk()
    ycbv()
    bunny()
