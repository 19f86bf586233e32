"""The ``pcdet`` command. The only place that prints progress or exits; the library returns and raises."""
from __future__ import annotations

import contextlib
import dataclasses
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Optional

import numpy as np
import typer
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    TextColumn,
    TimeElapsedColumn,
)
from rich.table import Table
from rich.text import Text

from . import __version__
from .console import console, fail, guard, out_console
from .image.cli import image_app
from .io.outputs import check_file, check_folder
from .resources import shipped

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  rich_markup_mode=None,  # help texts are plain text: "pcdet[ray]" keeps its brackets
                  help="Find known rigid objects in depth data and estimate their 6-DoF poses.")
config_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None, help="Pipeline configuration.")
app.add_typer(config_app, name="config")
app.add_typer(image_app, name="image")

MODELS_DIR = shipped("models")


def _pipeline(pipeline: Optional[str], seed: Optional[int], grouping: Optional[str] = None):
    from .config import load_pipeline

    cfg = load_pipeline(pipeline)
    if seed is not None:
        cfg = cfg.replace(seed=seed)
    if grouping is not None:
        cfg = cfg.replace(grouping={"method": grouping})
    return cfg


def _library(models: Path, cfg, units: str):
    from .library import ModelLibrary

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with console.status(f"loading models from {models}"):
            lib = ModelLibrary.from_path(models, cfg, units=units)
    for w in caught:
        console.print(f"[yellow]warning:[/] {escape(str(w.message))}", highlight=False, soft_wrap=True)
    for n in lib.notes:
        if not any(n == str(w.message) for w in caught):
            console.print(f"[cyan]note:[/] {escape(n)}", highlight=False, soft_wrap=True)
    return lib


@app.command()
@guard
def detect(models: Path = typer.Option(MODELS_DIR, help="Folder of object models (meshes or clouds; BOP "
                                       "models/), or one model file."),
           depth: Optional[Path] = typer.Option(None, help="16-bit depth PNG."),
           camera: Optional[Path] = typer.Option(None, help="Camera JSON (fx, fy, cx, cy, width, height, "
                                                 "depth_scale; or BOP cam_K/depth_scale)."),
           rgb: Optional[Path] = typer.Option(None, help="Colour image for the overlay."),
           cloud: Optional[Path] = typer.Option(None, help="Point cloud in the sensor frame (PLY/PCD)."),
           out: Path = typer.Option(..., help="Detections JSON to write."),
           overlay: Optional[Path] = typer.Option(None, help="PNG picture of the detections."),
           pipeline: Optional[str] = typer.Option(None, help="Preset name (pipelines/NAME.toml) or TOML file."),
           grouping: Optional[str] = typer.Option(None, help="Grouping method: ransac, gc or hough."),
           units: str = typer.Option("auto", help="Model units: auto, m, cm, mm."),
           seed: Optional[int] = typer.Option(None, help="Random seed (overrides the pipeline's)."),
           ):
    """Detect the library's objects in one depth image or point cloud."""
    from .detector import Detector
    from .frame import Frame
    from .io.depth import write_png
    from .io.results import write_detections_json

    if (depth is None) == (cloud is None):
        fail("give either --depth with --camera, or --cloud")
    if depth is not None and camera is None:
        fail("--depth needs --camera (a camera JSON)")
    check_file(out, "detections JSON")
    if overlay:
        check_file(overlay, "overlay PNG")
    cfg = _pipeline(pipeline, seed, grouping)
    frame = Frame.from_depth_png(depth, camera, rgb_path=rgb) if depth else Frame.from_cloud(cloud)
    lib = _library(models, cfg, units)
    res = Detector(lib, cfg).detect(frame)
    write_detections_json(out, frame.info, res, cfg.to_dict(), __version__)
    _print_detections(res)
    if overlay:
        from .viz import overlay as draw

        write_png(overlay, draw(frame, res.detections, lib, cfg.preprocess.voxel))
        console.print(f"overlay: {overlay}")
    console.print(f"detections: {out}")


def _print_detections(res):
    t = Table(title=f"{len(res.detections)} detection(s) in {sum(res.timing_s.values()):.2f} s")
    for c in ("model", "obj_id", "score", "x (m)", "y (m)", "z (m)", "group", "inliers", "visible"):
        t.add_column(c, justify="right" if c != "model" else "left")
    for d in res.detections:
        x, y, z = d.T_cam_model[:3, 3]
        t.add_row(d.model, str(d.obj_id), f"{d.score:.3f}", f"{x:.3f}", f"{y:.3f}", f"{z:.3f}", str(d.group_size),
                  str(d.n_inliers), f"{d.visible_fraction:.2f}")
    out_console.print(t)


@app.command()
@guard
def run(recording: Path = typer.Argument(..., help="Recording or dataset folder: BOP, TUM RGB-D, Redwood log "
                                         "layout, depth/ + camera.json, or a folder of clouds."),
        models: Optional[Path] = typer.Option(None, help="Model folder (default: the dataset's models/)."),
        out: Path = typer.Option(..., help="Output folder: results.csv, frames/*.json, config.toml."),
        format: str = typer.Option("auto", help="Reader: auto, bop, tum, redwood, 7scenes, folder, clouds."),
        targets: Optional[str] = typer.Option(None, help="'gt': localise the objects listed in scene_gt.json; "
                                              "'bop19' or a JSON file: only the images of a BOP target list "
                                              "(test_targets_bop19.json), its objects and counts."),
        pipeline: Optional[str] = typer.Option(None, help="Preset name or TOML file."),
        grouping: Optional[str] = typer.Option(None, help="Grouping method: ransac, gc or hough."),
        units: str = typer.Option("auto", help="Model units: auto, m, cm, mm (BOP models/: mm)."),
        seed: Optional[int] = typer.Option(None, help="Random seed (overrides the pipeline's)."),
        resume: bool = typer.Option(False, help="Continue the run in OUT: keep its frames, detect the rest (OUT "
                                    "must have been written from the same recording with the same pipeline)."),
        overwrite: bool = typer.Option(False, help="Start over in an OUT that holds an earlier run (its frames and "
                                       "result files are removed first)."),
        track: bool = typer.Option(False, help="Track objects through the recording (full detection on the "
                                   "first frame, on the frame after a map pose was set, every --redetect-every "
                                   "frames and where tracking fails; ICP from the predicted pose between); writes "
                                   "results.csv, frames/ and tracks.json, and resumes with --resume."),
        redetect_every: int = typer.Option(15, help="With --track: full detection every N frames (0: only on "
                                           "the first frames, to confirm new map poses and where tracking "
                                           "fails)."),
        workers: int = typer.Option(1, help="Processes to spread frames (with --track: scenes) over; with "
                                    "--executor ray, the CPUs of a local Ray instance."),
        threads: Optional[int] = typer.Option(None, help="Detector threads when --workers is 1 (default: the "
                                              "machine's cores). Results do not depend on it."),
        executor: str = typer.Option("local", help="local (processes here) or ray (needs pcdet[ray])."),
        ray_address: Optional[str] = typer.Option(None, help="Ray cluster to use (default: start a local one)."),
        times: bool = typer.Option(False, help="Write measured times into results.csv (default -1, so that "
                                   "reruns are byte-identical)."),
        ):
    """Detect objects in every frame of a recording or dataset."""
    from .datasets import open_recording
    from .runner import RunFolder, RunOptions

    if workers < 1:
        fail(f"--workers must be >= 1, got {workers}")
    if threads is not None and threads < 1:
        fail(f"--threads must be >= 1, got {threads}")
    if executor not in ("local", "ray"):
        fail(f"--executor takes local or ray, got {executor!r}")
    if resume and overwrite:
        fail("--resume keeps what OUT holds and --overwrite removes it: give one of them")
    if track and targets:
        fail("--track follows each scene from its first frame: it takes no --targets")
    if track and resume and (workers > 1 or executor != "local"):
        fail("--track --resume continues from the checkpoints of a run in this process: use --workers 1 and the "
             "local executor")
    cfg = _pipeline(pipeline, seed, grouping)
    rec = open_recording(recording, format)
    if len(rec) == 0:
        fail(f"{recording}: no frames")
    if targets == "gt" and rec.targets(rec.images[0]) is None:
        fail(f"{recording}: --targets gt needs per-frame labels (a BOP scene_gt.json); this is a {rec.format} "
              "recording")
    if targets not in (None, "gt"):
        _use_target_list(rec, targets, recording)
    models = models or rec.models_dir
    if models is None:
        fail(f"{recording}: no models/ folder; pass --models")
    folder = RunFolder(out, rec, cfg, resume=resume, overwrite=overwrite, targets=_targets_used(rec, targets),
                       mode="track" if track else "detect", version=__version__)
    try:
        lib = _library(models, cfg, units)
        if track:
            return _run_tracking(rec, lib, cfg, folder.path, redetect_every, workers, executor, ray_address,
                                 resume=resume, times=times)
        return _run_detection(rec, lib, cfg, folder, RunOptions(
            targets=targets is not None, resume=resume, workers=workers, threads=threads, executor=executor,
            ray_address=ray_address, record_time=times, version=__version__))
    finally:
        folder.close()


def _use_target_list(rec, spec: str, recording: Path) -> None:
    """``--targets bop19`` or ``--targets FILE``: keep only the images of a BOP target list (``restrict_to``)."""
    if rec.format != "bop":
        fail(f"{recording}: --targets {spec} reads a BOP target list; this is a {rec.format} recording")
    rec.restrict_to(spec)
    if len(rec) == 0:
        fail(f"{recording}: no image of the target list {rec.target_file}")


def _targets_used(rec, targets: Optional[str]):
    """What ``run.json`` records of ``--targets``: False, True for gt, or the target list's file and digest (so
    that ``--resume`` with another list is refused)."""
    if targets in (None, "gt"):
        return targets == "gt"
    import hashlib

    digest = hashlib.sha256(rec.target_file.read_bytes()).hexdigest()[:16]
    return f"{rec.target_file.resolve()} (sha256 {digest})"


def _run_detection(rec, lib, cfg, folder, opts):
    from .runner import describe, run_recording

    out = folder.path
    with _progress(rate=True) as prog:
        task = prog.add_task("detecting", total=len(rec), dets=0)
        count = {"d": 0}

        def on_image(ref, res, err):
            count["d"] += len(res.detections) if res else 0
            if err:
                prog.console.print(f"[yellow]skipped[/] {describe(ref)}: {escape(err)}", highlight=False,
                                   soft_wrap=True)
            prog.update(task, advance=1, dets=count["d"])

        s = run_recording(rec, lib, cfg, folder, opts, on_image=on_image)
        prog.update(task, completed=len(rec))
    med = float(np.median(s.seconds)) if s.seconds else 0.0
    kept = f", {s.resumed} kept from before" if s.resumed else ""
    console.print(f"{rec.format}: {s.images} frame(s) detected{kept}, {s.detections} detection(s), median "
                  f"{med:.2f} s/frame, {len(s.failed)} failed -> {out / 'results.csv'}")
    if s.failed:
        raise typer.Exit(2 if s.images + s.resumed == 0 else 0)


def _run_tracking(rec, lib, cfg, out: Path, redetect_every: int, workers: int, executor: str,
                  ray_address: str | None, *, resume: bool = False, times: bool = False):
    from .tracking import (
        TrackingConfig,
        frames_by_scene,
        track_into,
        track_recording,
        write_tracked_frame,
        write_tracking_outputs,
    )

    tcfg = TrackingConfig(redetect_every=redetect_every)
    with _progress(rate=True, detections=False) as prog:
        task = prog.add_task("tracking", total=len(rec))
        tick = lambda i, mode, s: prog.update(task, advance=1)  # noqa: E731
        if workers <= 1 and executor == "local":
            res = track_into(rec, lib, cfg, out, tcfg, resume=resume, version=__version__, record_time=times,
                             on_frame=tick)
        else:  # scenes spread over processes or Ray: each scene's frames are written when it comes back
            res = track_recording(rec, lib, cfg, tcfg, workers=workers, executor=executor, ray_address=ray_address,
                                  on_frame=tick)
            for sid, r in res.items():
                for i, ref in enumerate(frames_by_scene(rec)[sid]):
                    write_tracked_frame(out, rec, ref, r, i, pipeline=cfg.to_dict(), version=__version__)
            write_tracking_outputs(out, rec, res, cfg, version=__version__, record_time=times)
        prog.update(task, completed=len(rec))
    modes = [m for r in res.values() for m in r.modes]
    by_scene = frames_by_scene(rec)
    for sid, r in res.items():
        for f, m in zip(by_scene[sid], r.modes):
            if m.startswith("failed"):
                console.print(f"[yellow]skipped[/] scene {sid} image {f.im_id}: {escape(m[8:])}", highlight=False,
                              soft_wrap=True)
    tr = [s for r in res.values() for s, m in zip(r.seconds, r.modes) if m == "track"]
    fps = f", tracking frames {1 / np.median(tr):.1f} frames/s" if tr else ""
    console.print(f"{len(rec)} frame(s) in {len(res)} scene(s), {modes.count('detect')} full detection(s), "
                  f"{sum(len(r.tracks) for r in res.values())} track(s){fps} -> {out / 'results.csv'}, "
                  f"{out / 'tracks.json'}")


@app.command()
@guard
def odometry(recording: Path = typer.Argument(..., help="Recording folder: BOP, TUM RGB-D, Redwood, 7-Scenes (a "
                                              "sequence, or a scene of seq-NN sequences), depth/ + camera.json."),
             out: Path = typer.Option(..., help="Output folder: trajectory.txt (TUM format) and odometry.toml."),
             format: str = typer.Option("auto", help="Reader: auto, bop, tum, redwood, 7scenes, folder."),
             method: Optional[str] = typer.Option(None, help="icp (point-to-plane ICP against a map of "
                                                  "keyframes; the default), kiss (KISS-ICP) or kiss+icp (KISS-ICP's "
                                                  "pose corrected by that ICP)."),
             config: Optional[Path] = typer.Option(None, help="TOML file with an [odometry] table of settings "
                                                   "(OdometryConfig; a run's odometry.toml reads back as it is); "
                                                   "--method overrides its method."),
             ):
    """Estimate the camera trajectory of a recording (T_world_cam per frame, the first camera as the world)."""
    from .config import load_odometry_config
    from .datasets import open_recording
    from .errors import InputError
    from .odometry import OdometryConfig
    from .odometry_run import errors_against, run_odometry, write_odometry

    if method not in (None, "kiss", "icp", "kiss+icp"):
        fail(f"--method takes kiss, icp or kiss+icp, got {method!r}")
    cfg = load_odometry_config(config) if config is not None else OdometryConfig()
    cfg = cfg if method is None else dataclasses.replace(cfg, method=method)
    rec = open_recording(recording, format)
    if len(rec) == 0:
        fail(f"{recording}: no frames")
    made = not out.exists()
    check_folder(out, "output folder")  # before the work: an unwritable OUT fails at once
    with _progress(rate=True, detections=False) as prog:
        task = prog.add_task("odometry", total=len(rec))

        def on_frame(ref, err):
            if err:
                prog.console.print(f"[yellow]skipped[/] scene {ref.scene_id} image {ref.im_id}: {escape(err)}",
                                   highlight=False, soft_wrap=True)
            prog.update(task, advance=1)

        run = run_odometry(rec, cfg, on_frame=on_frame)
    if not run.poses:
        if made:  # nothing to write: leave no empty folder behind
            with contextlib.suppress(OSError):
                out.rmdir()
        fail(f"{recording}: no frame could be read")
    files = write_odometry(out, run, cfg)
    recovered = f", {run.recovered} recovered (ICP had lost the map)" if run.recovered else ""
    console.print(f"{len(run.poses)} frame(s), odometry {run.frames_per_second:.1f} frames/s, {len(run.failed)} "
                  f"skipped{recovered} -> {', '.join(str(f) for f in files)}")
    try:
        truth = rec.camera_poses()
    except InputError as e:  # the trajectory stands without them: say why there are no errors
        console.print(f"[yellow]warning:[/] no ATE / RPE: {escape(str(e))}", highlight=False, soft_wrap=True)
        truth = None
    if truth:
        t = Table(title="against the recording's camera poses")
        for c in ("scene", "frames", "ATE (mm)", "RPE (mm)", "RPE (deg)"):
            t.add_column(c, justify="right")
        for sid, (ate, rt, rr) in errors_against(run, truth).items():
            n = sum(r.scene_id == sid for r in run.poses)
            t.add_row(str(sid), str(n), f"{ate * 1000:.1f}", f"{rt * 1000:.1f}", f"{rr:.2f}")
        out_console.print(t)


class _RateColumn(ProgressColumn):
    """Frames per second over the last few frames."""

    def render(self, task) -> Text:
        return Text(f"{task.speed:.2f} frames/s" if task.speed else "-- frames/s")


def _progress(detections: bool = True, rate: bool = False):
    cols = [TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn()]
    if rate:
        cols.append(_RateColumn())
    if detections:
        cols.append(TextColumn("{task.fields[dets]} detections"))
    return Progress(*cols, TimeElapsedColumn(), console=console)


@app.command()
@guard
def register(source: Path = typer.Argument(..., help="Model or cloud to move (mesh, PLY/PCD/XYZ)."),
             target: Path = typer.Argument(..., help="Scan to align it to."),
             out: Optional[Path] = typer.Option(None, help="JSON file for T_target_source."),
             voxel: Optional[float] = typer.Option(None, help="Sampling (m); default diameter / 40."),
             grouping: Optional[str] = typer.Option(None, help="Grouping method: ransac, gc or hough."),
             units: str = typer.Option("auto", help="Units of both files: auto, m, cm, mm."),
             seed: int = typer.Option(0, help="Random seed."),
             ):
    """Align SOURCE to TARGET with no initial guess (global alignment, then ICP)."""
    from .io.atomic import atomic_write_text
    from .register import RegisterConfig
    from .register import register as do_register

    if out:
        check_file(out, "registration JSON")
    with console.status("registering"), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = do_register(source, target, RegisterConfig(voxel=voxel, grouping=grouping or "ransac", seed=seed),
                        units=units)
    for w in caught:
        console.print(f"[yellow]warning:[/] {escape(str(w.message))}", highlight=False, soft_wrap=True)
    np.set_printoptions(precision=6, suppress=True)
    out_console.print("T_target_source =")
    out_console.print(str(r.T_target_source))
    console.print(f"fitness {r.fitness:.3f}, coverage {r.coverage:.3f}, rmse {r.rmse_m * 1000:.2f} mm, "
                  f"{r.n_inliers} inlier matches, "
                  f"{sum(r.timing_s.values()):.2f} s")
    if out:
        atomic_write_text(out, json.dumps({"source": str(source), "target": str(target),
                                           "T_target_source": np.round(r.T_target_source, 9).tolist(),
                                           "fitness": r.fitness, "coverage": r.coverage, "rmse_m": r.rmse_m,
                                           "n_inliers": r.n_inliers,
                                           "timing_s": r.timing_s, "pcdet_version": __version__}, indent=1))
        console.print(f"written: {out}")


@app.command()
@guard
def synth(models: Path = typer.Option(MODELS_DIR, help="Folder of mesh models."),
          out: Path = typer.Option(..., help="Output BOP dataset folder."),
          scenes: int = typer.Option(20, help="Number of scenes (one image each)."),
          objects: int = typer.Option(4, help="Library objects per scene."),
          instances: int = typer.Option(1, help="Up to this many copies of each chosen object."),
          distractors: int = typer.Option(0, help="Clutter objects per scene that are not in the library."),
          sequence: int = typer.Option(0, help="Frames per scene from a camera moving around the table "
                                       "(0: one image per scene)."),
          seed: int = typer.Option(0, help="Random seed."),
          noise: bool = typer.Option(True, help="Apply the sensor model."),
          sensor: str = typer.Option("structured_light_band", help="Sensor model: structured_light_band (Kinect-"
                                     "like: noise correlated between neighbouring pixels, quantised disparity, and "
                                     "objects' edges seen past as a real Kinect does), structured_light (the same "
                                     "noise, edge pixels dropped instead; the default until 2026-12) or "
                                     "independent (per-pixel noise)."),
          mesh_error: float = typer.Option(1.2, help="mm RMS: render each object from a copy of its mesh moved "
                                           "along its normals by a smooth random field this size (correlated over "
                                           "13 mm), as a real object differs from its scan; models/ keeps the "
                                           "meshes as given (0: off, the meshes exactly as the models)."),
          units: str = typer.Option("auto", help="Model units: auto, m, cm, mm."),
          overwrite: bool = typer.Option(False, help="Replace the scenes an earlier synth wrote into OUT."),
          ):
    """Render synthetic table-top scenes with exact ground truth, as a BOP dataset."""
    from .config import PipelineConfig
    from .synth import SynthConfig, check_synth_folder, synthesize

    if mesh_error < 0:
        fail(f"--mesh-error must be >= 0 (mm RMS), got {mesh_error:g}")
    cfg = SynthConfig(scenes=scenes, objects=objects, instances=instances, distractors=distractors, seed=seed,
                      noise=noise, sensor=sensor, sequence=sequence, mesh_error=mesh_error / 1000.0)
    check_synth_folder(check_folder(out, "dataset folder"), overwrite=overwrite)
    lib = _library(models, PipelineConfig(), units)
    with _progress(detections=False) as prog:
        task = prog.add_task("rendering", total=scenes)
        synthesize(lib, out, cfg, overwrite=overwrite, progress=lambda i, n: prog.update(task, completed=i))
    console.print(f"{scenes} scene(s) -> {out}")


@app.command("eval")
@guard
def eval_cmd(dataset: Path = typer.Argument(..., help="BOP dataset with ground truth."),
             results: Path = typer.Argument(..., help="BOP results CSV."),
             models: Optional[Path] = typer.Option(None, help="Model folder (default: DATASET/models)."),
             json_out: Optional[Path] = typer.Option(None, "--json", help="Write the tables as JSON."),
             units: str = typer.Option("auto", help="Model units."),
             targets: Optional[str] = typer.Option(None, help="'bop19' or a JSON file: score as BOP'19 does, on "
                                                   "the images and objects of a BOP target list "
                                                   "(test_targets_bop19.json), instances at least 10 % visible, "
                                                   "the inst_count best estimates of each."),
             ):
    """Score a BOP results file: ADD, ADD-S, MSSD, MSPD recall and BOP-style AR, per object and overall."""
    from .config import PipelineConfig
    from .datasets.bop import VISIB_GT_MIN, BopDataset
    from .evaluate import evaluate, load_symmetries
    from .io.atomic import atomic_write_text
    from .io.bop import ROTATION_EXACT, read_results_csv

    if json_out:
        check_file(json_out, "evaluation JSON")
    ds = BopDataset(dataset)
    if targets not in (None, "gt"):  # gt: every instance of scene_gt.json, the default
        _use_target_list(ds, targets, dataset)
    models = models or ds.models_dir
    if models is None:
        fail(f"{dataset}: no models/ folder; pass --models")
    rows = read_results_csv(results)
    fixed = [r for r in rows if r["R_deviation"] > ROTATION_EXACT]
    if fixed:
        worst = max(fixed, key=lambda r: r["R_deviation"])
        console.print(f"note: {escape(str(results))}: R re-orthonormalised in {len(fixed)} row(s) (largest "
                      f"deviation of R R^T from I {worst['R_deviation']:.3g}, line {worst['line']})",
                      highlight=False, soft_wrap=True)
    lib = _library(models, PipelineConfig(), units)
    ev = evaluate(ds, rows, lib, symmetries=load_symmetries(models, lib), source=results)
    for w in ev.warnings:
        console.print(f"[yellow]warning:[/] {escape(str(results))}: {escape(w)}", highlight=False, soft_wrap=True)
    _print_eval(ev, lib)
    if ds.target_list is not None:
        console.print(f"scored as BOP'19 on the target list {escape(str(ds.target_file))}: {len(ds)} image(s), "
                      f"{ev.overall['instances']} instance(s) at least {VISIB_GT_MIN:g} visible", highlight=False,
                      soft_wrap=True)
    if json_out:
        atomic_write_text(json_out, json.dumps(ev.to_dict(), indent=1, default=float))
        console.print(f"written: {json_out}")


def _print_eval(ev, lib):
    cols = [("instances", "{}", "GT"), ("estimates", "{}", "est"), ("recall_add", "{:.3f}", "ADD"),
            ("recall_adds", "{:.3f}", "ADD-S"), ("precision_adds", "{:.3f}", "prec"),
            ("ar_vsd", "{:.3f}", "AR_VSD"), ("ar_mssd", "{:.3f}", "AR_MSSD"), ("ar_mspd", "{:.3f}", "AR_MSPD"),
            ("ar", "{:.3f}", "AR")]
    t = Table(title="recall at ADD / ADD-S < 0.1 d (each matched by its own error), precision (ADD-S), BOP average "
                    "recall (VSD, MSSD, MSPD); ADD, MSSD and MSPD up to the symmetries of models_info.json")
    t.add_column("object")
    for _, _, h in cols:
        t.add_column(h, justify="right")
    for oid, s in ev.per_object.items():
        name = next((m.name for m in lib if m.obj_id == oid), str(oid))
        t.add_row(f"{name} ({oid})", *[f.format(s.get(c, 0)) for c, f, _ in cols])
    t.add_row("[bold]all[/]", *[f.format(ev.overall.get(c, 0)) for c, f, _ in cols])
    out_console.print(t)


@app.command()
@guard
def diagnose(dataset: Path = typer.Argument(..., help="BOP dataset with ground truth."),
             models: Optional[Path] = typer.Option(None, help="Model folder (default: DATASET/models)."),
             targets: Optional[str] = typer.Option("gt", help="'gt': give the detector the objects present (BOP "
                                                   "localisation); 'none': search the whole library; 'bop19' or "
                                                   "a JSON file: the images, objects and counts of a BOP target "
                                                   "list."),
             pipeline: Optional[str] = typer.Option(None, help="Preset name or TOML file."),
             grouping: Optional[str] = typer.Option(None, help="Grouping method: ransac, gc or hough."),
             metric: str = typer.Option("add", help="Pose error: add or adds (for symmetric objects)."),
             limit: int = typer.Option(0, help="Diagnose only the first N frames (0: all)."),
             units: str = typer.Option("auto", help="Model units."),
             json_out: Optional[Path] = typer.Option(None, "--json", help="Write every instance's diagnosis."),
             depth_only: bool = typer.Option(False, "--depth-only", help="Drop the colour images (as in LM-O's "
                                             "depth-only evaluation)."),
             ):
    """Attribute every ground-truth instance to the stage that found or lost it (pcdet.diagnose)."""
    from .datasets.bop import BopDataset
    from .detector import Detector
    from .diagnose import STAGES, Diagnosis, diagnose_frame
    from .io.atomic import atomic_write_text

    if metric not in ("add", "adds"):
        fail(f"--metric takes add or adds, got {metric!r}")
    if json_out:
        check_file(json_out, "diagnosis JSON")
    cfg = _pipeline(pipeline, None, grouping)
    ds = BopDataset(dataset)
    if targets not in ("gt", "none"):
        _use_target_list(ds, targets, dataset)
    models = models or ds.models_dir
    if models is None:
        fail(f"{dataset}: no models/ folder; pass --models")
    det = Detector(_library(models, cfg, units), cfg)
    refs = ds.images[:limit] if limit else ds.images
    rows = []
    with _progress(detections=False, rate=True) as prog:
        task = prog.add_task("diagnosing", total=len(refs))
        for ref in refs:
            frame = ds.frame(ref)
            if depth_only:
                frame = dataclasses.replace(frame, rgb=None)
            tg = None if targets == "none" else ds.targets(ref)
            rows += diagnose_frame(det, frame, ds.scored_gt(ref), tg, metric=metric, scene_id=ref.scene_id,
                                   im_id=ref.im_id)
            prog.update(task, advance=1)
    diag = Diagnosis(rows)
    t = Table(title=f"{metric.upper()} in diameters; kp: scene keypoints of the model's grid on the instance / "
                    "with a correct match / of those, grouped; clusters: the grouped ones per scene cluster (grouped "
                    "apart)")
    for c in ("scene", "image", "obj", "visib", "kp", "clusters", "raw", "best raw", "refined", "best refined", "rank",
              "kept", "kept score", "best score", "stage"):
        t.add_column(c, justify="left" if c == "stage" else "right", min_width={"kp": 9, "stage": 12}.get(c))
    for r in rows:
        vis = "-" if r.visib_fract is None else f"{r.visib_fract:.2f}"
        t.add_row(str(r.scene_id), str(r.im_id), str(r.obj_id), vis,
                  f"{r.keypoints_on}/{r.keypoints_matched}/{r.keypoints_grouped}",
                  "+".join(map(str, r.grouped_clusters)) or "-", str(r.raw_hypotheses),
                  f"{r.best_raw:.3f}",
                  "yes" if r.best_raw_refined else "no", f"{r.best_refined:.3f}", str(r.rank), f"{r.kept_error:.3f}",
                  f"{r.kept_score:.3f}", f"{r.best_terms.get('score', -1):.3f}", r.stage)
    out_console.print(t)
    secs = [r.seconds for r in rows]
    out_console.print("  ".join(f"{k}: {v}" for k, v in diag.stages.items() if k in STAGES)
                      + f"  (of {len(rows)}; median {np.median(secs) if secs else 0:.2f} s/frame)")
    if json_out:
        atomic_write_text(json_out, json.dumps(diag.to_dict(), indent=1))
        console.print(f"written: {json_out}")


@app.command()
@guard
def demo(out: Path = typer.Option(Path("demo_out"), help="Output folder."),
         scenes: int = typer.Option(3, help="Synthetic scenes to make."),
         seed: int = typer.Option(0, help="Random seed."),
         ):
    """Synthesise scenes from the shipped models, detect, evaluate, and draw an overlay."""
    from .config import load_pipeline
    from .datasets.bop import BopDataset
    from .evaluate import evaluate
    from .io.bop import read_results_csv
    from .io.depth import write_png
    from .runner import RunOptions, run_recording
    from .synth import SynthConfig, synthesize
    from .viz import overlay as draw

    check_folder(out, "demo folder")  # the demo rewrites its own outputs in OUT on every run
    cfg = load_pipeline("default").replace(seed=seed)
    lib = _library(MODELS_DIR, cfg, "auto")
    data = out / "dataset"
    t0 = time.perf_counter()
    with console.status("rendering synthetic scenes"):
        synthesize(lib, data, SynthConfig(scenes=scenes, objects=4, seed=seed), overwrite=True)
    ds = BopDataset(data)
    with _progress() as prog:
        task = prog.add_task("detecting", total=len(ds), dets=0)
        count = {"d": 0}
        results = {}

        def on_image(img, res, err):
            count["d"] += len(res.detections) if res else 0
            results.setdefault("first", (img, res))  # drawn below, without detecting again
            prog.update(task, advance=1, dets=count["d"])

        s = run_recording(ds, lib, cfg, out / "run", RunOptions(version=__version__, overwrite=True),
                          on_image=on_image)
    ev = evaluate(ds, read_results_csv(out / "run" / "results.csv"), lib)
    _print_eval(ev, lib)
    img, res = results["first"]
    write_png(out / "overlay.png", draw(ds.frame(img), res.detections if res else [], lib, cfg.preprocess.voxel))
    console.print(f"median {np.median(s.seconds):.2f} s per image; total {time.perf_counter() - t0:.1f} s")
    console.print(f"dataset: {data}\nresults: {out / 'run' / 'results.csv'}\noverlay: {out / 'overlay.png'}")


@config_app.command("dump")
@guard
def config_dump(pipeline: Optional[str] = typer.Option(None, help="Preset name or TOML file (default: defaults)."),
                ):
    """Print the resolved pipeline configuration as TOML."""
    from .config import dump_toml

    typer.echo(dump_toml(_pipeline(pipeline, None)))


@app.command()
def version():
    """Print the version, and whether the compiled kernels were built (without them, numpy and scipy compute the
    same results more slowly)."""
    from . import align, cloud, features, graph, grid, lrf, residuals
    from .grouping import hough

    out_console.print(__version__)
    kernels = {"graph": graph.compiled(), "residuals": residuals.compiled(), "grid": grid.compiled(),
               "fpfh": features.compiled(), "align": align.compiled(), "normals": cloud.compiled(),
               "lrf": lrf.compiled(), "votes": hough.compiled()}
    built = [name for name, ok in kernels.items() if ok]
    missing = [name for name, ok in kernels.items() if not ok]
    line = f"compiled kernels: {', '.join(built) or 'none'}"
    if missing:
        line += f" (not built: {', '.join(missing)}; numpy and scipy compute the same results more slowly, FPFH " \
                "and normals open3d; reinstall with a C compiler to build them)"
    out_console.print(line, highlight=False)


def main():
    """Entry point of the ``pcdet`` command: runs the app, Ctrl-C ends with exit code 130."""
    try:
        app()
    except KeyboardInterrupt:
        console.print("interrupted")
        sys.exit(130)


if __name__ == "__main__":
    main()
