"""Many instances of meshes pcdet's authors did not make: recall and precision without targets.

The library is built from the real data in ../shared/data, not from ``models/``:
- cat: LINEMOD's scanned, textured cat (linemod_cat/models, mm);
- bunny: the Stanford bunny's zippered mesh (bunny/bun_zipper_res3.ply, m);
- gelatin_box, foam_brick: YCB-Video's point sets of the two boxes (ycbv_frame/models, mm), meshed as their
  convex hulls (the objects are convex);
- mug: YCB-Video's mug point set, meshed by screened Poisson reconstruction (open3d, depth 7, one thread so
  that the mesh is the same every run; the 5 % least supported vertices removed). The handle survives; the
  inside of the cup is closed over.
PCL's milk carton is not used: its model is a single view cut out of a scene, and has no back to render.

Scenes: ``pcdet synth --objects 2 --instances 3 --distractors 3``: two of the five meshes per scene, each with
one to three copies, among three random clutter shapes (boxes, cylinders, cones, spheres, capsules) that are
not in the library; ``pcdet synth``'s default sensor model and mesh error (``--sensor``, ``--mesh-error``).
Every pipeline searches all five models and is told nothing. Scores, from ``pcdet.evaluate``: recall at ADD-S
< 0.1 d, precision (share of detections within ADD-S 0.1 d of a ground-truth instance), and the median seconds
per frame; per object and overall.

Run:  python scripts/bench_thirdparty.py [--scenes 20] [--seed 2026] [--pipelines default,crowded+ransac]
          [--sensor structured_light_band] [--mesh-error 1.2] [--workdir DIR]
With ``--workdir DIR`` the meshes are kept in DIR/meshes and the scenes in DIR/suite (a BOP dataset, for
``pcdet run``, ``pcdet eval`` and ``pcdet diagnose --targets none --metric adds``); a later run with the same
DIR reuses the scenes.
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

import numpy as np

from pcdet.config import load_pipeline
from pcdet.datasets.bop import BopDataset
from pcdet.detector import Detector
from pcdet.evaluate import evaluate
from pcdet.library import ModelLibrary
from pcdet.synth import SynthConfig, synthesize

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def _ycbv_points(oid: int) -> np.ndarray:
    import open3d as o3d

    return np.asarray(o3d.io.read_point_cloud(str(DATA / "ycbv_frame" / "models" / f"obj_{oid:06d}.ply")).points)


def _poisson(points: np.ndarray):
    """A closed mesh over a point set (N, 3): normals from 20 neighbours, oriented consistently and outwards,
    screened Poisson at octree depth 7, the 5 % least supported vertices removed."""
    import open3d as o3d
    import trimesh

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(20))
    pc.orient_normals_consistent_tangent_plane(20)
    n = np.asarray(pc.normals)
    if np.mean(np.sum((points - points.mean(0)) * n, axis=1)) < 0:
        pc.normals = o3d.utility.Vector3dVector(-n)
    mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pc, depth=7, n_threads=1)
    density = np.asarray(density)
    mesh.remove_vertices_by_mask(density < np.quantile(density, 0.05))
    return trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.triangles))


def third_party_models(out: Path) -> Path:
    """Write the five meshes (PLY, each in its source's units) into ``out``; returns ``out``."""
    import trimesh

    out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(DATA / "linemod_cat" / "models" / "obj_000006.ply", out / "cat.ply")
    shutil.copyfile(DATA / "bunny" / "bun_zipper_res3.ply", out / "bunny.ply")
    trimesh.convex.convex_hull(_ycbv_points(8)).export(out / "gelatin_box.ply")
    trimesh.convex.convex_hull(_ycbv_points(21)).export(out / "foam_brick.ply")
    _poisson(_ycbv_points(14)).export(out / "mug.ply")
    return out


def main():
    from bench_crowded import detect_all  # scripts/ is on the path when this file is run

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--sensor", default=SynthConfig.sensor, help="pcdet synth's sensor model")
    ap.add_argument("--mesh-error", type=float, default=SynthConfig.mesh_error * 1000,
                    help="mm RMS: objects rendered from bent copies of their meshes, as pcdet synth --mesh-error")
    ap.add_argument("--pipelines", default="default,crowded+ransac",
                    help="comma-separated presets (names, a+b layered, or TOML paths)")
    ap.add_argument("--workdir", type=Path, default=None,
                    help="keep the meshes and scenes here (default: a temporary folder); reused when present")
    args = ap.parse_args()
    tmp = tempfile.TemporaryDirectory()
    work = args.workdir or Path(tmp.name)
    suite = work / "suite"
    if not (suite / "test").is_dir():
        meshes = third_party_models(work / "meshes")
        synthesize(ModelLibrary.from_folder(meshes), suite,
                   SynthConfig(scenes=args.scenes, objects=2, instances=3, distractors=3, seed=args.seed,
                               sensor=args.sensor, mesh_error=args.mesh_error / 1000))
    else:
        print(f"scenes from {suite} (--scenes, --seed, --sensor and --mesh-error do not apply)")
    ds = BopDataset(suite)
    lib = ModelLibrary.from_folder(suite / "models")
    frames = [(img, ds.frame(img)) for img in ds]
    rows = []
    for pipe in args.pipelines.split(","):
        ests, times = detect_all(Detector(lib, load_pipeline(pipe)), frames)
        ev = evaluate(ds, ests, lib, with_vsd=False)
        for oid, r in sorted(ev.per_object.items()):
            rows.append((pipe, lib[lib.index_of(oid)].name, r["instances"], r["estimates"], r["recall_adds"],
                         r["precision_adds"], None))
        ov = ev.overall
        rows.append((pipe, "all", ov["instances"], ov["estimates"], ov["recall_adds"], ov["precision_adds"],
                     float(np.median(times))))
        print(f"{pipe:16s} recall ADD-S {ov['recall_adds']:.3f}  precision {ov['precision_adds']:.3f}  "
              f"median {np.median(times):.2f} s/frame", flush=True)
    print(f"\n{len(frames)} frames, {len(lib)}-model library ({', '.join(m.name for m in lib)}), no targets")
    print("| pipeline | object | instances | detections | recall ADD-S | precision | median s/frame |")
    print("|---|---|---|---|---|---|---|")
    for p, name, n, e, r, pr, t in rows:
        print(f"| {p} | {name} | {n} | {e} | {r:.3f} | {pr:.3f} | {'' if t is None else f'{t:.2f}'} |")


if __name__ == "__main__":
    main()
