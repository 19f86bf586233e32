"""Object models: surface samples with outward normals, keypoints, FPFH and diameter, cached on disk.

A model comes from a mesh (PLY/OBJ/STL/OFF/GLB) or a point cloud (PLY without faces, PCD, XYZ). Units are
metres inside pcdet; files in millimetres (BOP) are scaled, and obvious cases are detected and reported.
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from .cloud import diameter as _diameter
from .cloud import estimate_normals, voxel_downsample
from .config import PipelineConfig
from .errors import InputError
from .features import fpfh
from .io.atomic import atomic_write_bytes
from .keypoints import select_keypoints

MESH_SUFFIXES = {".ply", ".obj", ".stl", ".off", ".glb", ".gltf"}
CLOUD_ONLY_SUFFIXES = {".pcd", ".xyz", ".xyzn", ".pts"}
MODEL_SUFFIXES = MESH_SUFFIXES | CLOUD_ONLY_SUFFIXES
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
CACHE_VERSION = 8
# An object wider than this many "metres" is certainly in mm (table-top and warehouse objects are < 3 m).
MM_DETECT_EXTENT = 3.0


class UnitsWarning(UserWarning):
    """A model's size suggests other units than the ones it was loaded with."""


@dataclass
class ObjectModel:
    """One object of the library, in metres, in the model file's own frame.

    points, normals : (N, 3) float64 surface samples (one per voxel) and outward unit normals.
    kp_points, kp_normals : (K, 3) keypoints and their normals as seen in rendered partial views (model frame);
    features : (K, 33) float32 FPFH of each, computed on that view alone (as a sensor would see it);
    kp_lrfs : (K, 3, 3) SHOT local reference frames (rows x, y, z, model frame) from the same view, NaN where
        the view had too few points around the keypoint.
    diameter : largest distance between two model points (m).
    vertices, faces : (V, 3) float64 m and (F, 3) int64 when the model is a mesh, else None.
    scale : factor applied to the file's coordinates to get metres.
    """

    name: str
    obj_id: int
    path: str
    points: np.ndarray
    normals: np.ndarray
    kp_points: np.ndarray
    kp_normals: np.ndarray
    features: np.ndarray
    kp_lrfs: np.ndarray
    diameter: float
    scale: float = 1.0
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def is_mesh(self) -> bool:
        return self.faces is not None and len(self.faces) > 0


def _hash_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _model_params(cfg: PipelineConfig) -> dict:
    return {"voxel": cfg.preprocess.voxel, "normal_radius": cfg.preprocess.normal_radius,
            "normal_max_nn": cfg.preprocess.normal_max_nn, "keypoints": vars(cfg.keypoints),
            "features": vars(cfg.features), "model": vars(cfg.model), "version": CACHE_VERSION}


def default_cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "pcdet" / "models"


def _read_geometry(path: Path):
    """(vertices (V,3), faces (F,3) or None, normals (V,3) or None) in file units."""
    import trimesh

    suffix = path.suffix.lower()
    if suffix in CLOUD_ONLY_SUFFIXES:
        from .io.clouds import read_cloud

        cd = read_cloud(path)
        return cd.points, None, cd.normals
    try:
        geom = trimesh.load(str(path), process=False)
    except Exception as e:  # trimesh raises many types for unreadable files; report it as the file's problem
        raise InputError(f"cannot read model ({type(e).__name__}: {e})", path) from None
    if isinstance(geom, trimesh.Scene):
        meshes = [g for g in geom.dump() if isinstance(g, trimesh.Trimesh)] if len(geom.geometry) else []
        if not meshes:
            raise InputError("model file holds no mesh geometry", path)
        geom = trimesh.util.concatenate(meshes)
    if isinstance(geom, trimesh.Trimesh) and len(geom.faces) > 0:
        return np.asarray(geom.vertices, float), np.asarray(geom.faces, np.int64), None
    verts = np.asarray(getattr(geom, "vertices", np.zeros((0, 3))), float)
    normals = None
    if suffix == ".ply" and len(verts):  # point-only PLY: take its normals if it has them
        from .io.clouds import read_cloud

        normals = read_cloud(path, keep_invalid=True).normals
    return verts, None, normals


def _resolve_scale(verts: np.ndarray, units, path: Path, notes: list[str]) -> float:
    extent = float(np.ptp(verts, axis=0).max())
    if units in (None, "auto"):
        if extent > MM_DETECT_EXTENT:
            notes.append(f"{path.name}: {extent:.0f} units wide, read as millimetres")
            return 0.001
        return 1.0
    scale = UNITS.get(units) if isinstance(units, str) else float(units)
    if scale is None:
        raise InputError(f"unknown units {units!r}; use one of {sorted(UNITS)}, 'auto' or a number", path)
    if extent * scale > MM_DETECT_EXTENT:
        warnings.warn(f"{path}: model is {extent * scale:.1f} m wide when read as {units}; is it in millimetres?",
                      UnitsWarning, stacklevel=3)
    return scale


@dataclass
class Geometry:
    """A model file's geometry in metres: vertices (V, 3), faces (F, 3) or None (point cloud), per-vertex
    normals (V, 3) or None, the scale applied to the file's numbers, and notes about units."""

    vertices: np.ndarray
    faces: np.ndarray | None
    normals: np.ndarray | None
    scale: float
    notes: list[str]


def load_geometry(path, units="auto") -> Geometry:
    """Read a mesh or point-cloud model file, validate it and convert it to metres."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: model file not found")
    if path.suffix.lower() not in MODEL_SUFFIXES:
        raise InputError(f"unknown model format {path.suffix!r}; expected one of {sorted(MODEL_SUFFIXES)}", path)
    verts, faces, vnormals = _read_geometry(path)
    if faces is None:
        fin = np.isfinite(verts).all(axis=1)
        verts = verts[fin]
        vnormals = vnormals[fin] if vnormals is not None else None
    elif not np.isfinite(verts).all():
        raise InputError("mesh has non-finite vertex coordinates", path)
    if len(verts) < 3:
        raise InputError(f"model has {len(verts)} points; at least 3 are needed", path)
    notes: list[str] = []
    scale = _resolve_scale(verts, units, path, notes)
    return Geometry(verts * scale, faces, vnormals, scale, notes)


def build_model(path, cfg: PipelineConfig, units="auto", obj_id: int = 0, name: str | None = None,
                seed: int = 0) -> ObjectModel:
    """Load one model file and compute its samples, normals, keypoints and FPFH (no cache)."""
    path = Path(path)
    g = load_geometry(path, units)
    verts, faces, vnormals, scale, notes = g.vertices, g.faces, g.normals, g.scale, g.notes
    pp = cfg.preprocess
    if faces is not None:
        import trimesh

        mesh = trimesh.Trimesh(verts, faces, process=False)
        if mesh.area <= 0:
            raise InputError("mesh has zero surface area", path)
        count = int(min(400_000, max(5000, 8 * mesh.area / pp.voxel ** 2)))
        samples, fidx = trimesh.sample.sample_surface(mesh, count, seed=seed)
        # one real surface sample per voxel (voxel means would sit inside the surface at edges and corners)
        _, _, rep = voxel_downsample(np.asarray(samples), pp.voxel)
        pts, face_nrm = np.asarray(samples)[rep], np.asarray(mesh.face_normals)[fidx[rep]]
        # estimate normals exactly as the scene's are (PCA at the same radius), so that descriptors and pair
        # features compare like with like; the mesh only decides which way each normal points
        nrm = estimate_normals(pts, pp.normal_radius, pp.normal_max_nn, viewpoint=None)
        nrm[(nrm * face_nrm).sum(axis=1) < 0] *= -1
    else:
        pts, nrm, _ = voxel_downsample(verts, pp.voxel, vnormals)
        if nrm is None or not (np.linalg.norm(nrm, axis=1) > 0.5).all():
            nrm = _outward_normals(pts, pp.normal_radius, pp.normal_max_nn)
    if len(pts) < 10:
        raise InputError(f"model has only {len(pts)} samples at voxel {pp.voxel} m: is it tiny, or in the "
                         "wrong units?", path)
    vv = verts if faces is not None else None
    diameter = _diameter(verts if vv is not None else pts)  # a mesh's vertices give the exact value
    kpp, kpn, feats, lrfs = view_features(pts, nrm, vv, faces, diameter, cfg)
    if len(kpp) < 3:
        raise InputError("no view of the model yields keypoints: is it flat, tiny, or in the wrong units?", path)
    return ObjectModel(name or path.stem, int(obj_id), str(path), pts, nrm, kpp, kpn, feats, lrfs, diameter, scale,
                       vv, faces, notes)


def view_directions(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere (Fibonacci lattice), deterministic."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z ** 2)
    a = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([r * np.cos(a), r * np.sin(a), z], axis=1)


def view_features(points, normals, vertices, faces, diameter: float, cfg: PipelineConfig):
    """Keypoints, normals and FPFH of the model as seen from ``cfg.model.views`` viewpoints.

    For each viewpoint (on a sphere of radius ``cfg.model.view_distance`` m around the model's centre) the
    samples that the sensor would see are kept (rendered depth agrees, normal faces the camera); normals are
    re-estimated on that partial cloud and oriented to the camera, and FPFH is computed on it, exactly as for a
    scene. Returns ``(kp_points (K, 3), kp_normals (K, 3), features (K, 33), lrfs (K, 3, 3))`` in the model
    frame (LRF rows NaN where invalid).
    """
    from .lrf import shot_lrf
    from .camera import Camera
    from .render import render_meshes, render_points

    pp, mc = cfg.preprocess, cfg.model
    centre = (points.max(0) + points.min(0)) / 2
    f = 575.0
    cam = Camera(f, f, 159.5, 159.5, 320, 320)
    while f * diameter / mc.view_distance > 300:  # keep the object in the image
        f *= 0.8
        cam = Camera(f, f, 159.5, 159.5, 320, 320)
    out_p, out_n, out_f, out_l = [], [], [], []
    for d in view_directions(mc.views):
        eye = centre + d * mc.view_distance
        z = -d
        up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        x = np.cross(up, z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])  # rows: camera axes in the model frame
        T_cam_model = np.eye(4)
        T_cam_model[:3, :3] = R
        T_cam_model[:3, 3] = -R @ eye
        pc = points @ R.T + T_cam_model[:3, 3]
        nc = normals @ R.T
        if vertices is not None:
            depth = render_meshes(cam, [(vertices, faces, T_cam_model)]).depth
        else:
            depth = render_points(cam, pc, pp.voxel)
        uv = np.rint(cam.project(pc)).astype(np.int64)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        vis = np.zeros(len(pc), bool)
        dz = depth[uv[inside, 1], uv[inside, 0]]
        vis[inside] = (dz > 0) & (np.abs(pc[inside, 2] - dz) < pp.voxel)
        vis &= (nc * pc).sum(axis=1) < 0  # facing the camera
        if vis.sum() < 20:
            continue
        vp = pc[vis]
        vn = estimate_normals(vp, pp.normal_radius, pp.normal_max_nn)  # toward the camera, as in a scene
        kp = select_keypoints(vp, cfg.keypoints)
        feats = fpfh(vp, vn, kp, cfg.features)
        F, ok = shot_lrf(vp, vp[kp], cfg.features.lrf_support)
        F = F @ R  # camera-frame axes -> model-frame axes (rows)
        F[~ok] = np.nan
        Rt = R.T
        out_p.append((vp[kp] - T_cam_model[:3, 3]) @ R)
        out_n.append(vn[kp] @ Rt.T)
        out_f.append(feats)
        out_l.append(F)
    if not out_p:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 33), np.float32), np.zeros((0, 3, 3))
    return np.concatenate(out_p), np.concatenate(out_n), np.concatenate(out_f), np.concatenate(out_l)


def _outward_normals(pts: np.ndarray, radius: float, max_nn: int) -> np.ndarray:
    from ._o3d import o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pc.normals = o3d.utility.Vector3dVector(estimate_normals(pts, radius, max_nn, viewpoint=None))
    if len(pts) > 10:
        pc.orient_normals_consistent_tangent_plane(10)
    n = np.asarray(pc.normals).copy()
    # consistent orientation is up to one global sign: choose the one where most normals point away
    # from the centroid (outward for closed objects and for single views of convex-ish ones)
    if ((pts - pts.mean(axis=0)) * n).sum(axis=1).mean() < 0:
        n = -n
    return n


def _save(model: ObjectModel, path: Path) -> None:
    buf = io.BytesIO()
    meta = {k: getattr(model, k) for k in ("name", "obj_id", "path", "diameter", "scale", "notes")}
    arrays = {k: getattr(model, k) for k in ("points", "normals", "kp_points", "kp_normals", "features", "kp_lrfs")}
    if model.is_mesh:
        arrays.update(vertices=model.vertices, faces=model.faces)
    np.savez(buf, meta=np.array(json.dumps(meta)), **arrays)
    atomic_write_bytes(path, buf.getvalue())


def _load(path: Path) -> ObjectModel:
    with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        arrays = {k: z[k] for k in z.files if k != "meta"}
    return ObjectModel(**meta, **arrays)


def load_model(path, cfg: PipelineConfig | None = None, units="auto", obj_id: int = 0, name: str | None = None,
               cache_dir: Path | str | None | bool = None) -> ObjectModel:
    """A model, from the on-disk cache when the file's bytes and the parameters are unchanged.

    ``cache_dir=False`` disables the cache; ``None`` uses ``$XDG_CACHE_HOME/pcdet/models``.
    """
    cfg = cfg or PipelineConfig()
    path = Path(path)
    if cache_dir is False:
        return build_model(path, cfg, units, obj_id, name)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: model file not found")
    key_src = json.dumps({"file": _hash_file(path), "units": units, "obj_id": int(obj_id), "name": name,
                          "params": _model_params(cfg)}, sort_keys=True, default=str)
    key = hashlib.sha256(key_src.encode()).hexdigest()[:24]
    cdir = Path(cache_dir) if cache_dir else default_cache_dir()
    cpath = cdir / f"{path.stem}-{key}.npz"
    if cpath.is_file():
        try:
            m = _load(cpath)
            m.path = str(path)
            return m
        except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile):
            pass  # a corrupt (truncated: BadZipFile) or stale (other fields) cache entry is rebuilt below
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = build_model(path, cfg, units, obj_id, name)
    for w in caught:  # re-emit so callers see them on this first (uncached) load ...
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    m.notes.extend(str(w.message) for w in caught if issubclass(w.category, UnitsWarning))  # ... and later ones
    try:
        _save(m, cpath)
    except OSError:
        pass  # a read-only cache location only costs speed
    return m


class ModelLibrary:
    """The objects pcdet looks for: an ordered list of ``ObjectModel`` with lookup by name and id."""

    def __init__(self, models: list[ObjectModel]):
        if not models:
            raise InputError("model library is empty")
        ids = [m.obj_id for m in models]
        if len(set(ids)) != len(ids):
            raise InputError(f"model ids are not unique: {ids}")
        self.models = list(models)

    def __len__(self) -> int:
        return len(self.models)

    def __iter__(self) -> Iterator[ObjectModel]:
        return iter(self.models)

    def __getitem__(self, i: int) -> ObjectModel:
        return self.models[i]

    def by_id(self, obj_id: int) -> ObjectModel:
        for m in self.models:
            if m.obj_id == obj_id:
                return m
        raise KeyError(f"no model with obj_id {obj_id}")

    def by_name(self, name: str) -> ObjectModel:
        for m in self.models:
            if m.name == name:
                return m
        raise KeyError(f"no model named {name!r}")

    @property
    def notes(self) -> list[str]:
        return [n for m in self.models for n in m.notes]

    @classmethod
    def from_folder(cls, folder, cfg: PipelineConfig | None = None, units="auto",
                    cache_dir: Path | str | None | bool = None,
                    progress: Callable[[str], None] | None = None) -> "ModelLibrary":
        """Every model file in ``folder`` (sorted by name). A BOP ``models/`` folder (``models_info.json``
        beside ``obj_NNNNNN.ply``) keeps its ids and is read in millimetres unless ``units`` says otherwise;
        elsewhere ids are 1, 2, ... in file-name order and units are auto-detected."""
        folder = Path(folder)
        if not folder.is_dir():
            raise FileNotFoundError(f"{folder}: model folder not found")
        info_path = folder / "models_info.json"
        info = {}
        if info_path.is_file():
            try:
                info = json.loads(info_path.read_text())
            except json.JSONDecodeError as e:
                raise InputError(f"not valid JSON ({e})", info_path) from None
        files = sorted(p for p in folder.iterdir() if p.suffix.lower() in MODEL_SUFFIXES and p.is_file())
        if not files:
            raise InputError(f"no model files ({', '.join(sorted(MODEL_SUFFIXES))})", folder)
        models = []
        for i, p in enumerate(files, start=1):
            obj_id, name, u = i, p.stem, units
            if info and p.stem.startswith("obj_") and p.stem[4:].isdigit():
                obj_id = int(p.stem[4:])
                entry = info.get(str(obj_id), {})
                name = entry.get("name", p.stem)
                u = "mm" if units in (None, "auto") else units
            if progress:
                progress(name)
            models.append(load_model(p, cfg, u, obj_id, name, cache_dir))
        return cls(models)

    @classmethod
    def from_path(cls, path, cfg: PipelineConfig | None = None, units="auto",
                  cache_dir: Path | str | None | bool = None, progress=None) -> "ModelLibrary":
        """A folder of models (``from_folder``) or a single model file (id 1)."""
        path = Path(path)
        if path.is_file():
            return cls.from_files([path], cfg, units, cache_dir)
        return cls.from_folder(path, cfg, units, cache_dir, progress)

    @classmethod
    def from_files(cls, paths, cfg: PipelineConfig | None = None, units="auto", cache_dir=None) -> "ModelLibrary":
        return cls([load_model(p, cfg, units, i, None, cache_dir) for i, p in enumerate(paths, start=1)])
