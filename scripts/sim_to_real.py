"""The sim-to-real gap: how far synthetic depth is from a real Kinect, per sensor model of ``pcdet.sensor``.

Three measurements on the same real frames (default: ../shared/data/linemod_cat, a Kinect v1):
1. Depth noise. A plane is fitted to every 15 x 15 patch of valid depth that is smooth (residual RMS under
   4 mm); printed are the median residual RMS and the residual's autocorrelation along a row at 1-5 pixels.
   The same statistics for each sensor model, applied to a rendered plane at the real frames' median depth.
2. Edges. The object's mesh is rendered at its true pose; for the pixels 1, 2, 3 and 4-6 pixels inside its outline,
   the share where the depth lies behind the mesh (beyond the verification tolerance: the sensor sees past the
   object's edge) and the share with no depth, on the real frames and on their twins (below).
3. Detection. Each real frame gets a twin per sensor model: the object's mesh is rendered at its true pose and put
   in front of the real depth (wherever the render is in front of it, or the real depth has no return), the whole
   passes through the sensor model, and the object's pixels are kept. The rest of the frame, clutter and colour
   included, stays real, so the twin differs from the real frame only in how the object itself looks to the sensor.
   The detector runs on the real frame and on every twin with the object given; printed per variant: frames found
   (ADD < 0.1 d), scene keypoints on the object and the share of them whose FPFH candidates include a correct
   match, the best raw hypothesis's error (diameters), the RMS of measured minus rendered depth 4 px or more inside
   the outline at the pose found (how far the measured surface lies from the mesh), and the frames missed. A sensor
   model predicts the real frames when its twins score as the real frames do, and miss the same frames.

Run:  python scripts/sim_to_real.py [--data DIR] [--frames 20] [--no-detection]
          [--sensors structured_light,structured_light_band,independent,none] [--mesh-error MM]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy import ndimage

from pcdet.config import load_pipeline
from pcdet.datasets.bop import BopDataset
from pcdet.detector import Detector, Trace
from pcdet.diagnose import diagnose_frame
from pcdet.frame import Frame
from pcdet.library import ModelLibrary
from pcdet.metrics import add
from pcdet.render import render_meshes
from pcdet.sensor import SENSORS, apply_sensor
from pcdet.synth import SynthConfig, perturbed_mesh
from pcdet.verify import VerifyConfig

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"
PATCH = 15


def patch_statistics(depth: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residual RMS (m) and mean depth (m) of every smooth 15 x 15 patch, and the residual's row autocorrelation at
    lags 1-5 (P, 5)."""
    yy, xx = np.mgrid[0:PATCH, 0:PATCH]
    A = np.stack([xx.ravel(), yy.ravel(), np.ones(PATCH * PATCH)], axis=1)
    rms, mean, ac = [], [], []
    H, W = depth.shape
    for y in range(0, H - PATCH, PATCH):
        for x in range(0, W - PATCH, PATCH):
            p = depth[y:y + PATCH, x:x + PATCH]
            if (p <= 0).any():
                continue
            z = p.ravel().astype(float)
            r = (z - A @ np.linalg.lstsq(A, z, rcond=None)[0]).reshape(PATCH, PATCH)
            v = float((r * r).mean())
            if r.std() > 0.004 or v <= 0:
                continue
            rms.append(np.sqrt(v))
            mean.append(z.mean())
            ac.append([(r[:, lag:] * r[:, :-lag]).mean() / v for lag in range(1, 6)])
    return np.array(rms), np.array(mean), np.array(ac).reshape(-1, 5)


def noise_table(ds: BopDataset, refs, sensors: list[str]) -> None:
    stats = [patch_statistics(ds.frame(r).depth) for r in refs]
    rms = np.concatenate([s[0] for s in stats])
    z = np.concatenate([s[1] for s in stats])
    ac = np.concatenate([s[2] for s in stats])
    print(f"\nDepth noise on smooth 15 x 15 patches ({len(refs)} real frames; synthetic: a plane at the real "
          f"median depth, {np.median(z):.2f} m, 3 draws)")
    print("| depth | patches | residual RMS (mm) | autocorrelation at 1 / 2 / 3 / 4 / 5 px |")
    print("|---|---|---|---|")

    def row(name, rms, ac):
        print(f"| {name} | {len(rms)} | {np.median(rms) * 1000:.2f} | "
              f"{' / '.join(f'{v:.2f}' for v in np.median(ac, axis=0))} |")

    row("real", rms, ac)
    cam = ds.frame(refs[0]).camera
    yy, xx = np.mgrid[0:cam.height, 0:cam.width]
    plane = np.median(z) + 0.0006 * (yy - cam.height / 2) + 0.0002 * (xx - cam.width / 2)
    for name in sensors:
        rng = np.random.default_rng(0)
        st = [patch_statistics(apply_sensor(name, plane, rng, cam.fx) / 1000.0) for _ in range(3)]
        row(f"synthetic, {name}", np.concatenate([s[0] for s in st]), np.concatenate([s[2] for s in st]))


def twin(frame: Frame, model, T_cam_model: np.ndarray, sensor: str, rng: np.random.Generator, *,
         shape: tuple[np.ndarray, np.ndarray] | None = None) -> Frame:
    """The real ``frame`` with the object's depth replaced by its rendered mesh through ``sensor``: the mesh is put
    in front of the real depth, the whole passes through the sensor model, and the object's pixels are kept.
    ``shape``: (vertices, faces) rendered instead of the model's mesh (a copy bent by ``synth.perturbed_mesh``, as
    ``pcdet synth --mesh-error`` renders its objects)."""
    cam = frame.camera
    v, f = shape if shape is not None else (model.vertices, model.faces)
    r = render_meshes(cam, [(v, f, T_cam_model)])
    real = frame.depth
    front = (r.depth > 0) & ((real <= 0) | (r.depth < real + 0.01))
    # the sensor sees the object in front of the real background, so its edges are edges against that background
    scene = np.where(front, r.depth, real).astype(np.float64)
    synthetic = apply_sensor(sensor, scene, rng, cam.fx) / 1000.0
    depth = np.where(front, synthetic, real).astype(np.float32)
    return Frame(depth, cam, frame.rgb, dict(frame.info))


EDGE_BANDS = ((1, 1), (2, 2), (3, 3), (4, 6))  # pixels inside the outline, first to last


def edge_shares(depth: np.ndarray, rendered: np.ndarray, tolerance: float) -> np.ndarray:
    """(len(EDGE_BANDS), 3) pixel counts per band inside the outline of ``rendered`` (H, W) m (0: off the model):
    all, depth behind the model by more than ``tolerance`` m, and no depth."""
    inside = rendered > 0
    dist = np.ceil(ndimage.distance_transform_edt(inside))
    behind = (depth > 0) & (depth > rendered + tolerance)
    out = np.zeros((len(EDGE_BANDS), 3))
    for i, (lo, hi) in enumerate(EDGE_BANDS):
        band = inside & (dist >= lo) & (dist <= hi)
        out[i] = band.sum(), (band & behind).sum(), (band & (depth <= 0)).sum()
    return out


def edge_table(ds: BopDataset, refs, sensors: list[str]) -> None:
    lib = ModelLibrary.from_path(ds.models_dir, load_pipeline(None))
    tol = VerifyConfig().depth_tolerance
    counts = {name: np.zeros((len(EDGE_BANDS), 3)) for name in ["real"] + [f"twin, {s}" for s in sensors]}
    for i, ref in enumerate(refs):
        frame = ds.frame(ref)
        for g in ds.gt(ref):
            m = lib[lib.index_of(g["obj_id"])]
            r = render_meshes(frame.camera, [(m.vertices, m.faces, g["T_cam_model"])]).depth
            counts["real"] += edge_shares(frame.depth, r, tol)
            for s in sensors:
                t = twin(frame, m, g["T_cam_model"], s, np.random.default_rng(1000 + i))
                counts[f"twin, {s}"] += edge_shares(t.depth, r, tol)
    bands = " | ".join(f"{lo} px" if lo == hi else f"{lo}-{hi} px" for lo, hi in EDGE_BANDS)
    print(f"\nThe object's edge at its true pose ({len(refs)} frames): share of the pixels 1-6 px inside the outline "
          f"where the depth lies more than {tol * 1000:.0f} mm behind the mesh / has no depth")
    print(f"| depth | {bands} |")
    print("|---|" + "---|" * len(EDGE_BANDS))
    for name, c in counts.items():
        cells = " | ".join(f"{b / max(n, 1):.2f} / {z / max(n, 1):.2f}" for n, b, z in c)
        print(f"| {name} | {cells} |")


def surface_residual(trace: Trace, frame: Frame, lib: ModelLibrary, obj_id: int, T_true: np.ndarray,
                     tolerance: float) -> tuple[float, np.ndarray] | None:
    """At the kept pose of object ``obj_id`` of ``lib`` nearest ``T_true`` (``trace``: the detection in ``frame``):
    the RMS (m) of measured minus rendered depth over the pixels 4 or more px inside its outline (residuals beyond
    ``tolerance`` m left out), how far the surface the sensor measures lies from the mesh; and the edge counts of
    ``edge_shares`` there. None when no kept pose lies within 0.1 d of ``T_true`` (ADD)."""
    mi = lib.index_of(obj_id)
    model = lib[mi]
    kept = [trace.registrations[r].T_target_source for r in trace.kept
            if trace.hypotheses[trace.refined[r]].model_index == mi]
    found = sorted((add(T, T_true, model.points), i) for i, T in enumerate(kept))
    if not found or found[0][0] >= 0.1 * model.diameter:
        return None
    r = render_meshes(frame.camera, [(model.vertices, model.faces, kept[found[0][1]])]).depth
    inside = r > 0
    deep = inside & (ndimage.distance_transform_edt(inside) >= 4) & (frame.depth > 0)
    e = (frame.depth - r)[deep]
    e = e[np.abs(e) <= tolerance]
    return (float(np.sqrt(np.mean(e * e))) if len(e) else float("nan")), edge_shares(frame.depth, r, tolerance)


def detection_table(ds: BopDataset, refs, sensors: list[str], pipeline: str | None, mesh_error: float = 0.0) -> None:
    cfg = load_pipeline(pipeline)
    lib = ModelLibrary.from_path(ds.models_dir, cfg)
    det = Detector(lib, cfg)
    tol = cfg.verify.depth_tolerance
    shapes = {}
    if mesh_error > 0:  # each model bent once, as pcdet synth does (its default correlation length)
        rng = np.random.default_rng(2)
        shapes = {m.obj_id: perturbed_mesh(m.vertices, m.faces, mesh_error, SynthConfig().mesh_error_length, rng)
                  for m in lib}
    rows = {name: [] for name in ["real"] + [f"twin, {s}" for s in sensors]}
    surface = {name: [] for name in rows}
    for i, ref in enumerate(refs):
        frame, gts, targets = ds.frame(ref), ds.gt(ref), ds.targets(ref)
        ids = {"scene_id": ref.scene_id, "im_id": ref.im_id}
        tr = Trace()
        rows["real"] += diagnose_frame(det, frame, gts, targets, trace=tr, **ids)
        for g in gts:
            surface["real"].append(surface_residual(tr, frame, lib, g["obj_id"], g["T_cam_model"], tol))
        for s in sensors:
            rng = np.random.default_rng(1000 + i)
            for g in gts:
                m = lib[lib.index_of(g["obj_id"])]
                frame_t = twin(frame, m, g["T_cam_model"], s, rng, shape=shapes.get(m.obj_id))
                tr = Trace()
                rows[f"twin, {s}"] += diagnose_frame(det, frame_t, [g], targets, trace=tr, **ids)
                surface[f"twin, {s}"].append(surface_residual(tr, frame_t, lib, g["obj_id"], g["T_cam_model"], tol))
        print(f"  frame {i + 1}/{len(refs)}", flush=True)
    extra = f"; the twins' meshes bent by {mesh_error * 1000:.1f} mm RMS" if mesh_error > 0 else ""
    print(f"\nDetection with the object given ({len(refs)} frames; {pipeline or 'default'} pipeline{extra})")
    print("| frames | found (ADD < 0.1 d) | keypoints on the object (median) | share with a correct match (median) "
          "| best raw hypothesis (d, median) | surface residual at the pose found (mm RMS, median) "
          "| missed (image ids) |")
    print("|---|---|---|---|---|---|---|")
    for name, rs in rows.items():
        found = sum(r.stage == "found" for r in rs)
        on = np.median([r.keypoints_on for r in rs])
        share = np.median([r.keypoints_matched / max(r.keypoints_on, 1) for r in rs])
        raw = np.median([r.best_raw for r in rs])
        missed = ", ".join(str(r.im_id) for r in rs if r.stage != "found") or "none"
        res = [x[0] for x in surface[name] if x is not None]
        res_cell = f"{np.median(res) * 1000:.2f}" if res else "-"
        print(f"| {name} | {found} / {len(rs)} | {on:.0f} | {share:.3f} | {raw:.3f} | {res_cell} | {missed} |")
    at_pose = [x[1] for x in surface["real"] if x is not None]
    if at_pose:  # the edge table again, at the poses found instead of the dataset's (which may be a pixel off)
        c = np.sum(at_pose, axis=0)
        cells = ", ".join(f"{lo}{'' if lo == hi else f'-{hi}'} px {b / max(n, 1):.2f}" for (lo, hi), (n, b, _)
                          in zip(EDGE_BANDS, c))
        print(f"\nReal frames at the poses found ({len(at_pose)}): depth behind the mesh inside the outline at {cells}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA / "linemod_cat")
    ap.add_argument("--frames", type=int, default=20, help="Real frames used, evenly spread over the dataset.")
    ap.add_argument("--sensors", default=",".join(SENSORS))
    ap.add_argument("--pipeline", default=None)
    ap.add_argument("--no-detection", action="store_true", help="Only the noise and edge statistics.")
    ap.add_argument("--mesh-error", type=float, default=0.0,
                    help="mm RMS: in the detection table, render the twins from meshes bent as pcdet synth "
                         "--mesh-error bends them (a mesh off the real object; 0: off)")
    a = ap.parse_args()
    if a.mesh_error < 0:
        raise SystemExit("error: --mesh-error must be >= 0 (mm RMS)")
    sensors = [s for s in a.sensors.split(",") if s]
    for s in sensors:
        if s not in SENSORS:
            raise SystemExit(f"error: unknown sensor model {s!r}; known: {', '.join(SENSORS)}")
    ds = BopDataset(a.data)
    refs = ds.images[:: max(1, len(ds.images) // a.frames)][: a.frames]
    noise_table(ds, refs, sensors)
    edge_table(ds, refs, sensors)
    if not a.no_detection:
        detection_table(ds, refs, sensors, a.pipeline, a.mesh_error / 1000.0)


if __name__ == "__main__":
    main()
