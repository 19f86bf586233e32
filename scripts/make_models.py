"""Generate the sample models in models/: asymmetric machined parts built by CSG (trimesh + manifold3d).

Run: python scripts/make_models.py [--out models]. Writes obj_00000N.ply (millimetres, as BOP) and
models_info.json (diameter and bounding box in mm, names). Every part is chosen to have no rotational
symmetry, so a pose is unique and the metrics need no symmetry handling.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import trimesh
from trimesh.creation import box, cylinder


def _at(mesh: trimesh.Trimesh, xyz=(0, 0, 0), rot=None) -> trimesh.Trimesh:
    m = mesh.copy()
    if rot is not None:
        axis, angle = rot
        m.apply_transform(trimesh.transformations.rotation_matrix(np.radians(angle), axis))
    m.apply_translation(xyz)
    return m


def _union(*ms):
    return trimesh.boolean.union(list(ms), engine="manifold")


def _diff(a, *bs):
    return trimesh.boolean.difference([a, *bs], engine="manifold")


def bracket():
    """L-bracket with two holes in one leg and a gusset on one side."""
    base = box((80, 40, 6))
    leg = _at(box((6, 40, 50)), (37, 0, 28))
    gusset = _at(box((20, 5, 20)), (24, 17.5, 12), rot=((0, 1, 0), 45))
    holes = [_at(cylinder(4, 20), (x, 0, 0)) for x in (-25, 5)]
    return _diff(_union(base, leg, gusset), *holes)


def flange():
    """Round flange with an off-centre boss and three unevenly spaced bolt holes."""
    disc = cylinder(40, 8, sections=64)
    boss = _at(cylinder(15, 22, sections=48), (8, 0, 15))
    bore = _at(cylinder(7, 60, sections=32), (8, 0, 0))
    holes = [_at(cylinder(4, 20), (30 * np.cos(a), 30 * np.sin(a), 0)) for a in np.radians([20, 140, 250])]
    tab = _at(box((20, 14, 8)), (-44, 0, 0))
    return _diff(_union(disc, boss, tab), bore, *holes)


def clamp():
    """C-clamp frame: a thick C with a threaded-boss stub on one jaw."""
    outer = box((70, 20, 90))
    inner = _at(box((50, 30, 60)), (12, 0, 0))
    stub = _at(cylinder(8, 25), (-5, 0, 45 + 10))
    return _union(_diff(outer, inner), stub)


def elbow():
    """Pipe elbow: two tubes of different lengths at 90 degrees with a flange on the long arm."""
    a = _at(cylinder(14, 70, sections=40), (0, 0, 35))
    b = _at(cylinder(14, 45, sections=40), (22.5, 0, 0), rot=((0, 1, 0), 90))
    joint = trimesh.creation.icosphere(subdivisions=3, radius=14)
    fl = _at(cylinder(22, 6, sections=40), (0, 0, 70))
    bore_a = _at(cylinder(9, 80, sections=32), (0, 0, 40))
    bore_b = _at(cylinder(9, 50, sections=32), (25, 0, 0), rot=((0, 1, 0), 90))
    return _diff(_union(a, b, joint, fl), bore_a, bore_b)


def stepblock():
    """Stepped block with a slot and a chamfered corner."""
    s1 = box((90, 50, 20))
    s2 = _at(box((60, 50, 20)), (-15, 0, 20))
    s3 = _at(box((25, 50, 20)), (-32.5, 0, 40))
    slot = _at(box((12, 60, 12)), (20, 0, 6))
    cut = _at(box((30, 30, 80)), (45, 25, 10), rot=((0, 0, 1), 45))
    return _diff(_union(s1, s2, s3), slot, cut)


def tjoint():
    """T-shaped pipe joint with unequal branches and a side lug."""
    main = _at(cylinder(12, 100, sections=40), (0, 0, 0), rot=((0, 1, 0), 90))
    branch = _at(cylinder(10, 40, sections=40), (15, 0, 20))
    lug = _at(box((16, 30, 8)), (-30, 20, 0))
    bore = _at(cylinder(7, 110, sections=32), (0, 0, 0), rot=((0, 1, 0), 90))
    return _diff(_union(main, branch, lug), bore)


PARTS = [("bracket", bracket), ("flange", flange), ("clamp", clamp), ("elbow", elbow),
         ("stepblock", stepblock), ("tjoint", tjoint)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "models"))
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    info = {}
    for i, (name, fn) in enumerate(PARTS, start=1):
        mesh = fn()
        mesh.apply_translation(-mesh.bounding_box.centroid)  # model origin at its box centre
        assert mesh.is_watertight and mesh.volume > 0, name
        hull = mesh.convex_hull.vertices
        diam = float(np.sqrt(((hull[:, None] - hull[None]) ** 2).sum(-1).max()))
        lo, ext = mesh.bounds[0], mesh.extents
        path = out / f"obj_{i:06d}.ply"
        mesh.export(path, encoding="binary")
        info[str(i)] = {"name": name, "diameter": round(diam, 4),
                        "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
                        "size_x": float(ext[0]), "size_y": float(ext[1]), "size_z": float(ext[2])}
        print(f"{path.name}: {name:10s} {len(mesh.faces):6d} faces, diameter {diam:6.1f} mm")
    (out / "models_info.json").write_text(json.dumps(info, indent=1) + "\n")


if __name__ == "__main__":
    main()
