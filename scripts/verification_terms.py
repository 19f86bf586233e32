"""How well each verification term separates true poses from wrong ones on real frames.

Runs the detector (with the objects given, BOP localisation) on every STEP-th frame of each BOP dataset, with
every coarse candidate refined, and takes every pose that reached the full ICP. A pose is true when its ADD (ADD-S
with --adds) is under 0.1 diameters. For each candidate term it prints the area under the ROC curve (the chance
that a random true pose scores above a random wrong one) and how often the best-scoring pose of an object in a
frame is a true one (when one exists), and writes the score distributions as an SVG plot.

Terms: the verification score the detector ranks by (depth only), its parts, and two that are measured here
and not used by the detector: normal agreement (share of the supported pixels whose measured surface normal is
within 30 degrees of the model's) and colour agreement (share of them whose chromaticity is within 0.06 of the
model's vertex colour; only where the frame has RGB and the mesh has vertex colours).

usage: python scripts/verification_terms.py [--step 2] [--svg docs/verification_scores.svg] DATASET...
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from pcdet.datasets.bop import BopDataset
from pcdet.detector import Detector, Trace
from pcdet.library import ModelLibrary
from pcdet.metrics import add, adds

NORMAL_COS = np.cos(np.radians(30.0))
CHROMA_TOL = 0.06


def depth_normals(depth: np.ndarray, camera) -> np.ndarray:
    """(H, W, 3) unit normals of the measured surface from central differences of the back-projected depth
    image, facing the camera; NaN where a neighbour is missing or more than 2 cm away in depth."""
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w]
    P = np.stack([(u - camera.cx) / camera.fx * depth, (v - camera.cy) / camera.fy * depth, depth], axis=2)
    dx = np.full_like(P, np.nan)
    dy = np.full_like(P, np.nan)
    dx[:, 1:-1] = P[:, 2:] - P[:, :-2]
    dy[1:-1] = P[2:] - P[:-2]
    bad = np.zeros((h, w), bool)
    bad[:, 1:-1] |= (depth[:, 2:] == 0) | (depth[:, :-2] == 0) | (np.abs(depth[:, 2:] - depth[:, :-2]) > 0.02)
    bad[1:-1] |= (depth[2:] == 0) | (depth[:-2] == 0) | (np.abs(depth[2:] - depth[:-2]) > 0.02)
    n = np.cross(dx, dy)
    n /= np.linalg.norm(n, axis=2, keepdims=True) + 1e-12
    n[np.sum(n * P, axis=2) > 0] *= -1
    n[bad | (depth == 0)] = np.nan
    return n


def chroma(rgb: np.ndarray) -> np.ndarray:
    """(N, 3) colours -> (N, 2) chromaticity (r, g) / (r + g + b)."""
    c = np.asarray(rgb, float)[:, :3]
    return c[:, :2] / np.maximum(c.sum(axis=1, keepdims=True), 1.0)


def vertex_colours(mesh_path: Path, vertices_m: np.ndarray) -> np.ndarray | None:
    """(V, 3) vertex colours of the mesh file for ``vertices_m`` (the loaded model's vertices, matched to the
    file's by nearest neighbour in whatever unit the file uses), or None without colours."""
    import trimesh

    mesh = trimesh.load(mesh_path, process=False)
    cols = getattr(mesh.visual, "vertex_colors", None)
    if cols is None or len(cols) != len(mesh.vertices):
        return None
    src = np.asarray(mesh.vertices, float)
    scale = np.ptp(src, axis=0).max() / max(np.ptp(vertices_m, axis=0).max(), 1e-9)
    _, idx = cKDTree(src / scale).query(vertices_m)
    return np.asarray(cols)[idx, :3]


def auc(pos: np.ndarray, neg: np.ndarray) -> float:
    """P(a random positive scores above a random negative), ties counted half."""
    if not len(pos) or not len(neg):
        return float("nan")
    from scipy.stats import rankdata

    r = rankdata(np.concatenate([pos, neg]))
    return float((r[: len(pos)].sum() - len(pos) * (len(pos) + 1) / 2) / (len(pos) * len(neg)))


def collect(root: Path, step: int, use_adds: bool) -> list[dict]:
    """One row per refined pose: the label, the frame/object it belongs to and every term."""
    ds = BopDataset(root)
    lib = ModelLibrary.from_folder(ds.models_dir)
    det = Detector(lib, det_config())
    colours = {}
    for pm in det.models:
        m = pm.model
        path = getattr(m, "path", None)
        colours[pm.index] = vertex_colours(Path(path), m.vertices) if (m.is_mesh and path) else None
    rows = []
    for k, ref in enumerate(ds.images[::step]):
        frame = ds.frame(ref)
        trace = Trace()
        det.detect(frame, ds.targets(ref), trace=trace)
        normals = depth_normals(frame.depth, frame.camera).reshape(-1, 3)
        rgb = None if frame.rgb is None else frame.rgb.reshape(-1, 3)
        gts = ds.gt(ref)
        for r, j in enumerate(trace.refined):
            mi = trace.hypotheses[j].model_index
            m = lib[mi]
            T = trace.registrations[r].T_target_source
            truth = [g["T_cam_model"] for g in gts if g["obj_id"] == m.obj_id]
            err_fn = adds if use_adds else add
            err = min((err_fn(T, G, m.points) / m.diameter for G in truth), default=np.inf)
            v = trace.verifications[r]
            row = {"frame": (root.name, k), "obj": m.obj_id, "true": bool(err < 0.1), "score": v.score,
                   "fitness": v.fitness, "visible": v.visible_fraction,
                   "see-through": -v.n_violations / max(v.n_supported + v.n_violations, 1),
                   "normal": np.nan, "score x normal": np.nan, "colour": np.nan}
            pm = det.models[mi]
            if pm.caster is not None and len(v.support):
                _, nr, ids = pm.caster.cast(frame.camera, T, v.support)
                nm = normals[v.support]
                ok = np.isfinite(nm[:, 0]) & (ids >= 0)
                if ok.any():
                    row["normal"] = float(np.mean(np.abs(np.sum(nr[ok] * nm[ok], axis=1)) > NORMAL_COS))
                    row["score x normal"] = v.score * row["normal"]
                if rgb is not None and colours[mi] is not None and (ids >= 0).any():
                    hit = ids >= 0
                    face = m.faces[ids[hit]]
                    model_c = chroma(colours[mi][face].mean(axis=1))
                    frame_c = chroma(rgb[v.support[hit]])
                    row["colour"] = float(np.mean(np.linalg.norm(model_c - frame_c, axis=1) < CHROMA_TOL))
            rows.append(row)
        print(f"{root.name} frame {k + 1}/{len(ds.images[::step])}: {len(trace.refined)} refined poses",
              file=sys.stderr)
    return rows


def det_config():
    """The default pipeline, with every coarse candidate refined (not only the best few per object): the study
    is about how the score ranks poses, so it looks at all the detector could rank."""
    from pcdet.config import PipelineConfig

    cfg = PipelineConfig()
    return cfg.replace(refine={"max_per_model": cfg.refine.candidates})


TERMS = ("score", "fitness", "visible", "see-through", "normal", "score x normal", "colour")


def top_choice(rows: list[dict], term: str) -> tuple[int, int]:
    """(frames x objects where the best-by-``term`` pose is true, those where any pose is true)."""
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["frame"], r["obj"]), []).append(r)
    hit = n = 0
    for g in groups.values():
        if not any(r["true"] for r in g):
            continue
        vals = [r[term] for r in g if np.isfinite(r[term])]
        if not vals:
            continue
        n += 1
        best = max((r for r in g if np.isfinite(r[term])), key=lambda r: r[term])
        hit += best["true"]
    return hit, n


def svg(rows: list[dict], terms: list[str], path: Path, title: str) -> None:
    """Histograms (20 bins over the term's range, each class normalised to its own count) of true (green) and
    wrong (red) poses, one panel per term."""
    W, H, pad = 260, 170, 30
    cols = 3
    nrows = -(-len(terms) // cols)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{cols * W}" height="{nrows * H + 40}" '
           'font-family="sans-serif" font-size="11">',
           f'<text x="10" y="18" font-size="13">{title}</text>',
           '<text x="10" y="34" fill="#2a7">true poses (ADD &lt; 0.1 d)</text>'
           '<text x="170" y="34" fill="#c33">wrong poses</text>']
    for i, term in enumerate(terms):
        x0, y0 = (i % cols) * W, 40 + (i // cols) * H
        vals = np.array([r[term] for r in rows], float)
        lab = np.array([r["true"] for r in rows])
        ok = np.isfinite(vals)
        if not ok.any():
            continue
        lo, hi = float(vals[ok].min()), float(vals[ok].max())
        hi = hi if hi > lo else lo + 1
        edges = np.linspace(lo, hi, 21)
        pos, neg = vals[ok & lab], vals[ok & ~lab]
        a = auc(pos, neg)
        out.append(f'<text x="{x0 + pad}" y="{y0 + 14}">{term} (AUC {a:.2f}; {len(pos)} true, {len(neg)} wrong)'
                   '</text>')
        ph, pw = H - 50, W - pad - 10
        hist = [np.histogram(c, edges)[0] / max(len(c), 1) for c in (neg, pos)]
        top = max(max(hh.max() for hh in hist), 1e-9)
        bw = pw / 20
        for hh, colour in zip(hist, ("#c33", "#2a7")):
            for b, f in enumerate(hh):
                if f > 0:
                    bh = f / top * ph
                    out.append(f'<rect x="{x0 + pad + b * bw:.1f}" y="{y0 + 20 + ph - bh:.1f}" width="{bw:.1f}" '
                               f'height="{bh:.1f}" fill="{colour}" fill-opacity="0.5"/>')
        yb = y0 + 20 + ph
        out.append(f'<line x1="{x0 + pad}" y1="{yb}" x2="{x0 + pad + pw}" y2="{yb}" stroke="#000"/>')
        out.append(f'<text x="{x0 + pad}" y="{yb + 13}">{lo:.2f}</text>'
                   f'<text x="{x0 + pad + pw - 25}" y="{yb + 13}">{hi:.2f}</text>')
    out.append("</svg>")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text("\n".join(out) + "\n")
    tmp.replace(path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("datasets", nargs="+", type=Path)
    ap.add_argument("--step", type=int, default=1, help="Use every STEP-th frame.")
    ap.add_argument("--adds", action="store_true", help="Label by ADD-S instead of ADD (symmetric objects).")
    ap.add_argument("--svg", type=Path, default=None, help="Write the distributions here.")
    a = ap.parse_args()
    rows = []
    for root in a.datasets:
        rows += collect(root, a.step, a.adds)
    print(f"{len(rows)} refined poses, {sum(r['true'] for r in rows)} true")
    print(f"{'term':16s} {'AUC':>6s} {'best is true':>14s}")
    for term in TERMS:
        vals = np.array([r[term] for r in rows], float)
        lab = np.array([r["true"] for r in rows])
        ok = np.isfinite(vals)
        hit, n = top_choice(rows, term)
        print(f"{term:16s} {auc(vals[ok & lab], vals[ok & ~lab]):6.3f} {hit:>6d} / {n:<6d}")
    if a.svg:
        svg(rows, list(TERMS), a.svg, "Verification terms on " + ", ".join(p.name for p in a.datasets))
        print(f"written: {a.svg}")


if __name__ == "__main__":
    main()
