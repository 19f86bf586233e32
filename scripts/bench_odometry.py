"""Camera odometry against ground truth, pcdet's methods beside the peers in one run: Open3D's RGB-D odometry
(hybrid colour + depth term, frame to frame), Open3D's dense SLAM (KinectFusion-style: each frame against a ray
cast of a TSDF volume) and KISS-ICP as it ships (its default configuration, deskewing off because a depth image
is taken at one instant), with the trivial baselines (the camera never moves; the first true motion repeated).

Recordings: ../shared/data/sevenscenes (300 real Kinect frames, KinectFusion poses), ../shared/data/open3d_rgbd
(5 frames) and a synthetic table-top recording. Prints ATE (RMS position error after rigid alignment, mm), RPE
over one frame and over 30 (the drift; RMS, mm and deg) and frames/s of the odometry alone (frames are read
beforehand), and each method's frames/s as a ratio to pcdet's default.
Run:  python scripts/bench_odometry.py [--frames 60] [--seed 2026] [--data REC ... [--every N] [--backwards]]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from pcdet.datasets import open_recording
from pcdet.library import ModelLibrary
from pcdet.odometry import OdometryConfig
from pcdet.odometry import odometry as _odometry
from pcdet.odometry_run import relocalise
from pcdet.synth import SynthConfig, synthesize
from pcdet.trajectory import (
    ate_rmse,
    constant_velocity_baseline,
    identity_baseline,
    rpe,
)


def odometry(frames, cfg):
    """pcdet's odometry as `pcdet odometry` runs it (a frame that fits its map badly relocalised globally)."""
    return _odometry(frames, cfg, relocalise)


ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data"
DRIFT = 30  # frames over which the drift (RPE) is measured: 1 s of a 30 Hz camera


def open3d_rgbd_odometry(frames):
    """Open3D's frame-to-frame RGB-D odometry (hybrid term, default options), ``T_first_cam`` per frame; a
    frame it cannot register keeps the previous motion. Frames without colour use the depth as intensity."""
    import open3d as o3d

    cam = frames[0].camera
    intr = o3d.camera.PinholeCameraIntrinsic(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)
    option = o3d.pipelines.odometry.OdometryOption()
    jac = o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm()

    def rgbd(f):
        colour = f.rgb if f.rgb is not None else np.repeat((f.depth / max(f.depth.max(), 1e-6) * 255)
                                                           .astype(np.uint8)[..., None], 3, axis=2)
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray(colour)), o3d.geometry.Image(f.depth.astype(np.float32)),
            depth_scale=1.0, depth_trunc=4.0, convert_rgb_to_intensity=True)

    out, T, step = [np.eye(4)], np.eye(4), np.eye(4)
    prev = rgbd(frames[0])
    for f in frames[1:]:
        cur = rgbd(f)
        # source = cur, target = prev: the result takes cur's points into prev's frame, T_prev_cur
        ok, T_prev_cur, _ = o3d.pipelines.odometry.compute_rgbd_odometry(cur, prev, intr, np.eye(4), jac, option)
        step = T_prev_cur if ok else step
        T = T @ step
        out.append(T.copy())
        prev = cur
    return out


def open3d_dense_slam(frames, voxel=0.01):
    """Open3D's dense RGB-D SLAM (``open3d.t.pipelines.slam``, KinectFusion-style): each frame is tracked against a
    ray cast of the TSDF volume built so far, then fused into it. Options as in Open3D's dense_slam example
    (16^3 blocks, truncation 8 voxels, 7 cm depth-difference threshold), on the CPU; ``T_first_cam`` per frame."""
    import open3d as o3d
    import open3d.core as o3c

    dev = o3c.Device("CPU:0")
    cam = frames[0].camera
    K = o3c.Tensor(np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]]), o3c.float64)
    model = o3d.t.pipelines.slam.Model(voxel, 16, 40000, o3c.Tensor(np.eye(4)), dev)
    inp = o3d.t.pipelines.slam.Frame(cam.height, cam.width, K, dev)
    ray = o3d.t.pipelines.slam.Frame(cam.height, cam.width, K, dev)
    T, out = np.eye(4), []
    for i, f in enumerate(frames):
        depth = np.round(f.depth * 1000).astype(np.uint16)
        rgb = f.rgb if f.rgb is not None else np.zeros((cam.height, cam.width, 3), np.uint8)
        inp.set_data_from_image("depth", o3d.t.geometry.Image(o3c.Tensor(depth)).to(dev))
        inp.set_data_from_image("color", o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb))).to(dev))
        if i:
            try:
                T = T @ model.track_frame_to_model(inp, ray, 1000.0, 4.0, 0.07).transformation.cpu().numpy()
            except RuntimeError:  # Open3D raises when its linear system is singular: keep the last pose
                pass
        model.update_frame_pose(i, o3c.Tensor(T))
        model.integrate(inp, 1000.0, 4.0, 8.0)
        model.synthesize_model_frame(ray, 1000.0, 0.1, 4.0, 8.0, False)
        out.append(T.copy())
    return out


def kiss_as_shipped(frames):
    """KISS-ICP with its own default configuration (voxel = max_range / 100), deskewing off."""
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    kc = KISSConfig()
    kc.data.deskew = False
    kc.registration.max_num_threads = 1  # threaded reductions would make results depend on the thread count
    if kc.mapping.voxel_size is None:
        kc.mapping.voxel_size = kc.data.max_range / 100.0
    kiss = KissICP(kc)
    out = []
    for f in frames:
        pts, _ = f.points()
        kiss.register_frame(np.ascontiguousarray(pts), np.zeros(len(pts)))
        out.append(kiss.last_pose.copy())
    return out


def table(rec, label, every=1, backwards=False):
    """One table per sequence of ``rec`` (a 7-Scenes scene folder or a BOP dataset may hold several), of every
    ``every``-th frame (faster camera motion), last frame first if ``backwards`` (another path through the same
    room)."""
    scenes = sorted({r.scene_id for r in rec})
    label += f", one frame in {every}" if every > 1 else ""
    label += ", played backwards" if backwards else ""
    for sid in scenes:
        refs = [r for r in rec if r.scene_id == sid][::every]
        _table(rec, refs[::-1] if backwards else refs, label if len(scenes) == 1 else f"{label}, scene {sid}")


def _table(rec, refs, label):
    gtd = rec.camera_poses()
    gt = [np.linalg.inv(gtd[refs[0]]) @ gtd[r] for r in refs]
    frames = [rec.frame(r) for r in refs]
    print(f"\n{label}: {len(refs)} frames")
    print(f"| method | ATE (mm) | RPE (mm) | RPE (deg) | drift over {DRIFT} frames (mm / deg) | frames/s | "
          "speed vs pcdet default |")
    print("|---|---|---|---|---|---|---|")
    base = {}

    def row(name, est, fps=None):
        tr, rr = rpe(est, gt)
        drift = ""
        if len(est) > DRIFT:
            dt, dr = rpe(est, gt, DRIFT)
            drift = f"{dt * 1000:.1f} / {dr:.2f}"
        ratio = f"{fps / base['fps']:.2f}x" if fps and base.get("fps") else ""
        print(f"| {name} | {ate_rmse(est, gt) * 1000:.1f} | {tr * 1000:.1f} | {rr:.2f} | {drift} | "
              f"{'' if fps is None else f'{fps:.1f}'} | {ratio} |", flush=True)

    def timed(fn):
        t0 = time.perf_counter()
        est = fn()
        return est, len(frames) / (time.perf_counter() - t0)

    list(odometry(frames[:3], OdometryConfig()))  # warm-up: the first call's imports and caches are not timed
    est, fps = timed(lambda: list(odometry(frames, OdometryConfig())))
    base["fps"] = fps
    row("pcdet icp, keyframe map (default)", est, fps)
    row("pcdet icp without recovery (recover_below = 0)", *timed(lambda: list(odometry(frames, OdometryConfig(
        recover_below=0.0)))))
    row("pcdet frame-to-frame ICP", *timed(lambda: list(odometry(frames, OdometryConfig(
        keyframe_distance=0.0, keyframe_angle_deg=0.0, keyframes=1)))))
    row("pcdet kiss (KISS-ICP, 4 cm voxel)", *timed(lambda: list(odometry(frames, OdometryConfig(method="kiss")))))
    row("pcdet kiss+icp", *timed(lambda: list(odometry(frames, OdometryConfig(method="kiss+icp")))))
    row("KISS-ICP as it ships", *timed(lambda: kiss_as_shipped(frames)))
    row("Open3D RGB-D odometry (hybrid)", *timed(lambda: open3d_rgbd_odometry(frames)))
    row("Open3D dense SLAM (TSDF, frame to model, 1 cm)", *timed(lambda: open3d_dense_slam(frames)))
    row("identity (no motion)", identity_baseline(gt))
    row("constant velocity (first true step)", constant_velocity_baseline(gt))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--data", type=Path, nargs="*", default=None)
    ap.add_argument("--every", type=int, default=1, help="every n-th frame of --data (a faster camera)")
    ap.add_argument("--backwards", action="store_true", help="play --data from its last frame to its first")
    args = ap.parse_args()
    if args.every < 1:
        ap.error(f"--every must be >= 1, got {args.every}")
    if args.data:
        for d in args.data:
            table(open_recording(d), str(d), args.every, args.backwards)
        return
    for name, label in (("sevenscenes", "7-Scenes (real Kinect, KinectFusion poses)"),
                        ("open3d_rgbd", "open3d_rgbd (ICL-NUIM living room, rendered)")):
        if (DATA / name).is_dir():
            table(open_recording(DATA / name), label)
    with tempfile.TemporaryDirectory() as tmp:
        lib = ModelLibrary.from_folder(ROOT / "models")
        # the idealised scenes (edge pixels dropped, exact meshes), where docs/measurements.md's figures come from
        rec = synthesize(lib, Path(tmp) / "seq", SynthConfig(scenes=1, objects=4, sequence=args.frames,
                                                             seed=args.seed, sensor="structured_light",
                                                             mesh_error=0))
        table(open_recording(rec), f"synthetic table-top recording (pcdet synth --sequence {args.frames} "
                                   f"--seed {args.seed} --sensor structured_light --mesh-error 0)")


if __name__ == "__main__":
    main()
