"""Scan-to-scan and model-to-scan registration with no initial guess on real range scans: pcdet's ``register``
beside Open3D's recipe (FPFH + RANSAC on feature matches + point-to-plane ICP, as in its global-registration
tutorial) on the same pairs, in one run.

Pairs: every neighbouring pair of ../shared/data/stanford_scans (the dragon scanned every 24 degrees: pairs 24
and 48 degrees apart, 30 in all) and the bunny (scan bun045 onto bun000, and the mesh onto each scan). The true
T_target_source comes from the .conf files (a "bmesh FILE tx ty tz qx qy qz qw" line maps the scan's points X to
the common frame by R(q)^T X + t). A pair succeeds when the source points' RMS displacement between the found and
the true alignment is under 2 mm. Both methods get the same points (read beforehand, so file reading is not
timed) and sample at the same voxel (1/40 of the source's extent).

``--fragments N``: instead, room-scale scans in metres: Open3D's two 3DMatch-style fragments
(../shared/data/open3d_feature, about 5 cm apart, 1.5-2 m across), the source moved by N arbitrary rigid
motions (seeded: any rotation, a shift of about a metre along each axis). Their common frame is right to about
3 cm (their SOURCE.txt), so the reference is point-to-plane ICP from it; a registration succeeds within 2 cm RMS
and 1 degree of that reference.

``--scans DIR [DIR ...]``: instead, the scans of other folders in the Stanford layout (the scans as PLY files and
one .conf whose "bmesh" lines give their poses): each scan paired with the ``--steps`` next ones in the .conf's
order, round the end (on a turntable set such as the dragon's, its neighbours 1 and 2 positions away).

``--command``: also the cost of the command as a script calls it once a pair: the wall time of ``pcdet register
SRC TGT`` as a process (start, reading both PLY files, registering, printing), beside the in-process time of
reading the two files and of ``register`` on the arrays, and the start of ``pcdet register --help`` alone.

Run:  python scripts/bench_register.py [--limit N] [--gaps 24 48] [--fragments N] [--scans DIR ... [--steps 1 2]]
      [--command]
"""
from __future__ import annotations

import argparse
import dataclasses
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pcdet.cloud import diameter
from pcdet.io.clouds import read_cloud
from pcdet.io.models import load_geometry
from pcdet.register import RegisterConfig, register

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"
SUCCESS_M = 0.002


def read_conf(path: Path) -> dict[str, np.ndarray]:
    """``{file name: T_common_scan}`` from a Stanford .conf file."""
    out = {}
    for line in path.read_text().splitlines():
        w = line.split()
        if w and w[0] == "bmesh":
            T = np.eye(4)
            T[:3, :3] = Rotation.from_quat([float(v) for v in w[5:9]]).as_matrix().T
            T[:3, 3] = [float(v) for v in w[2:5]]
            out[w[1]] = T
    return out


def points(path: Path) -> np.ndarray:
    """A scan's points, or the bunny mesh's vertices (m)."""
    return load_geometry(path, units="m").vertices if "zipper" in path.name else read_cloud(path).points


def open3d_recipe(src: np.ndarray, tgt: np.ndarray, voxel: float, seed: int = 0) -> np.ndarray:
    """Open3D's global registration tutorial at ``voxel``: downsample, normals (2 voxel), FPFH (5 voxel), RANSAC
    on feature matches (distance 1.5 voxel, edge-length and distance checkers, 100k iterations, 0.999), then
    point-to-plane ICP (0.4 voxel). Returns T_target_source."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)

    def prep(p):
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p)).voxel_down_sample(voxel)
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
        f = reg.compute_fpfh_feature(pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
        return pc, f

    s, sf = prep(src)
    t, tf = prep(tgt)
    d = 1.5 * voxel
    res = reg.registration_ransac_based_on_feature_matching(
        s, t, sf, tf, True, d, reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(d)],
        reg.RANSACConvergenceCriteria(100000, 0.999))
    icp = reg.registration_icp(s, t, 0.4 * voxel, res.transformation, reg.TransformationEstimationPointToPlane())
    return np.asarray(icp.transformation)


def rms_displacement(T: np.ndarray, T_true: np.ndarray, pts: np.ndarray) -> float:
    d = pts @ (T[:3, :3] - T_true[:3, :3]).T + (T[:3, 3] - T_true[:3, 3])
    return float(np.sqrt(np.mean(np.sum(d ** 2, axis=1))))


def pairs(gaps=(24, 48)) -> list[tuple[Path, Path, np.ndarray, str]]:
    """(source, target, true T_target_source, label) for every pair in the benchmark: the dragon's scans
    ``gaps`` degrees apart (multiples of 24), then the bunny's."""
    out = []
    d = DATA / "stanford_scans"
    if d.is_dir():  # its .conf lists the scans every 24 degrees round the turntable
        out += scan_pairs(d, tuple(gap // 24 for gap in gaps))
    d = DATA / "bunny"
    if d.is_dir():
        conf = read_conf(d / "bun.conf")
        out.append((d / "bun045.ply", d / "bun000.ply", np.linalg.inv(conf["bun000.ply"]) @ conf["bun045.ply"],
                    "bunny scan 45 -> 0"))
        for scan in ("bun000.ply", "bun045.ply"):  # the mesh is in the common frame
            out.append((d / "bun_zipper_res3.ply", d / scan, np.linalg.inv(conf[scan]), f"bunny mesh -> {scan}"))
    return out


def scan_pairs(folder: Path, steps=(1, 2)) -> list[tuple[Path, Path, np.ndarray, str]]:
    """(source, target, true T_target_source, label) for every scan of ``folder`` (Stanford layout, module
    docstring) and each of the ``steps``-th next scans in its .conf's order, round the end."""
    confs = sorted(folder.glob("*.conf"))
    if len(confs) != 1:
        raise SystemExit(f"error: {folder}: {len(confs)} .conf files; one is needed (the scans' poses)")
    conf = read_conf(confs[0])
    names = list(conf)
    missing = [n for n in names if not (folder / n).is_file()]
    if missing or len(names) < 2:
        raise SystemExit(f"error: {confs[0]}: " + (f"names scans that are missing: {', '.join(missing)}" if missing
                                                   else "fewer than two bmesh lines"))
    out = []
    for step in steps:
        for i, a in enumerate(names):
            b = names[(i + step) % len(names)]
            if a == b:
                continue
            T = np.linalg.inv(conf[b]) @ conf[a]
            angle = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1, 1)))
            out.append((folder / a, folder / b, T, f"{Path(a).stem} -> {Path(b).stem} ({angle:.0f} deg)"))
    return out


def fragments(n: int, seed: int = 7) -> None:
    """The fragment pair under ``n`` rigid motions (module docstring): a table of both methods' errors and times."""
    import open3d as o3d
    from scipy.spatial.transform import Rotation

    d = DATA / "open3d_feature"
    src, tgt = (np.asarray(o3d.io.read_point_cloud(str(d / f"cloud_bin_{i}.pcd")).points) for i in (1, 0))
    s, t = (o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p)) for p in (src, tgt))
    t.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.1, max_nn=30))
    ref = np.asarray(o3d.pipelines.registration.registration_icp(
        s, t, 0.05, np.eye(4), o3d.pipelines.registration.TransformationEstimationPointToPlane()).transformation)
    voxel = diameter(src) / 40.0
    rng = np.random.default_rng(seed)

    def error(T: np.ndarray) -> tuple[float, float]:  # RMS displacement (m) and angle (deg) from the reference
        c = np.clip((np.trace(ref[:3, :3].T @ T[:3, :3]) - 1) / 2, -1, 1)
        return rms_displacement(T, ref, src), float(np.degrees(np.arccos(c)))

    print(f"Open3D's fragments, {len(src)} onto {len(tgt)} points, voxel {voxel * 1000:.0f} mm, {n} motions")
    print("| motion | pcdet error (mm / deg) | pcdet s | Open3D error (mm / deg) | Open3D s |")
    print("|---|---|---|---|---|")
    rows = []
    for i in range(n):
        G = np.eye(4)
        G[:3, :3] = Rotation.random(random_state=int(rng.integers(2 ** 31))).as_matrix()
        G[:3, 3] = rng.normal(0.0, 1.0, 3)
        moved = src @ G[:3, :3].T + G[:3, 3]
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = register(moved, tgt, RegisterConfig(voxel=voxel), units="m")
        t_p = time.perf_counter() - t0
        t0 = time.perf_counter()
        T_o = open3d_recipe(moved, tgt, voxel)
        t_o = time.perf_counter() - t0
        (ep, angle_p), (eo, angle_o) = error(r.T_target_source @ G), error(T_o @ G)
        rows.append((ep, angle_p, t_p, eo, angle_o, t_o))
        print(f"| {i} | {ep * 1000:.1f} / {angle_p:.2f} | {t_p:.2f} | {eo * 1000:.1f} / {angle_o:.2f} | "
              f"{t_o:.2f} |", flush=True)
    print("\n| method | within 2 cm and 1 deg | median s/pair | time vs pcdet |")
    print("|---|---|---|---|")
    tp = np.median([r[2] for r in rows])
    for name, e, a, ti in (("pcdet register", 0, 1, 2), ("Open3D FPFH + RANSAC + ICP", 3, 4, 5)):
        ok = sum(r[e] < 0.02 and r[a] < 1.0 for r in rows)
        tm = np.median([r[ti] for r in rows])
        print(f"| {name} | {ok}/{len(rows)} | {tm:.3f} | {tm / tp:.2f}x |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--limit", type=int, default=0, help="Only the first N pairs (0: all).")
    ap.add_argument("--iterations", type=int, default=None, help="pcdet's RANSAC draws (default: RegisterConfig's).")
    ap.add_argument("--gaps", type=int, nargs="+", default=[24, 48],
                    help="The dragon's pairs this many degrees apart (multiples of 24; default: 24 48).")
    ap.add_argument("--scans", type=Path, nargs="+", default=None,
                    help="Instead: the scans of these folders in the Stanford layout (scans + one .conf).")
    ap.add_argument("--steps", type=int, nargs="+", default=[1, 2],
                    help="With --scans: each scan with the scans this many places on in the .conf (default: 1 2).")
    ap.add_argument("--fragments", type=int, default=0,
                    help="Instead: Open3D's two room-scale fragments under this many rigid motions.")
    ap.add_argument("--command", action="store_true",
                    help="Also time `pcdet register SRC TGT` as a process a pair, against reading + registering.")
    a = ap.parse_args()
    if a.fragments:
        fragments(a.fragments)
        return
    if any(g % 24 or not 0 < g < 360 for g in a.gaps):
        ap.error(f"--gaps takes multiples of 24 between 24 and 336, got {a.gaps}")
    if any(n < 1 for n in a.steps):
        ap.error(f"--steps takes positive numbers, got {a.steps}")
    if a.scans:
        todo = [p for d in a.scans for p in scan_pairs(d, tuple(a.steps))][: a.limit or None]
    else:
        todo = pairs(tuple(a.gaps))[: a.limit or None]
    exe = shutil.which("pcdet") or str(Path(sys.executable).with_name("pcdet"))
    if a.command:
        starts = []
        for _ in range(5):
            t0 = time.perf_counter()
            subprocess.run([exe, "register", "--help"], check=True, capture_output=True)
            starts.append(time.perf_counter() - t0)
        print(f"`pcdet register --help` (the command's start): median {np.median(starts):.3f} s over 5 runs\n")
    extra = " command s | read s |" if a.command else ""
    print("| pair | pcdet error (mm) | pcdet s | Open3D error (mm) | Open3D s |" + extra)
    print("|---|---|---|---|---|" + ("---|---|" if a.command else ""))
    rows, command = [], []
    for src, tgt, T_true, label in todo:
        t0 = time.perf_counter()
        sp = points(src)
        tp_ = points(tgt)
        t_read = time.perf_counter() - t0
        voxel = diameter(sp) / 40.0
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cfg = RegisterConfig(voxel=voxel)
            if a.iterations:
                cfg = dataclasses.replace(cfg, iterations=a.iterations)
            r = register(sp, tp_, cfg, units="m")
        t_p = time.perf_counter() - t0
        e_p = rms_displacement(r.T_target_source, T_true, sp)
        t0 = time.perf_counter()
        T_o = open3d_recipe(sp, tp_, voxel)
        t_o = time.perf_counter() - t0
        e_o = rms_displacement(T_o, T_true, sp)
        rows.append((label, e_p, t_p, e_o, t_o))
        cells = ""
        if a.command:
            t0 = time.perf_counter()
            subprocess.run([exe, "register", str(src), str(tgt), "--units", "m", "--voxel", repr(voxel)],
                           check=True, capture_output=True)
            t_c = time.perf_counter() - t0
            command.append((t_c, t_read, t_p))
            cells = f" {t_c:.2f} | {t_read:.3f} |"
        print(f"| {label} | {e_p * 1000:.2f} | {t_p:.2f} | {e_o * 1000:.2f} | {t_o:.2f} |{cells}", flush=True)
    print("\n| method | within 2 mm | median s/pair | time vs pcdet |")
    print("|---|---|---|---|")
    tp = np.median([r[2] for r in rows])
    for name, ei, ti in (("pcdet register", 1, 2), ("Open3D FPFH + RANSAC + ICP", 3, 4)):
        ok = sum(r[ei] < SUCCESS_M for r in rows)
        tm = np.median([r[ti] for r in rows])
        print(f"| {name} | {ok}/{len(rows)} | {tm:.3f} | {tm / tp:.2f}x |")
    if command:
        wall, read, reg = (np.median([x[i] for x in command]) for i in range(3))
        print("\n| a pair, median s | command (process) | reading both files | register on arrays | the rest |")
        print("|---|---|---|---|---|")
        print(f"| pcdet | {wall:.3f} | {read:.3f} | {reg:.3f} | {wall - read - reg:.3f} |")


if __name__ == "__main__":
    main()
