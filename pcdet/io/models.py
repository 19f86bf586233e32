"""Model files: meshes (PLY/OBJ/STL/OFF/GLB/GLTF) and point clouds (PLY without faces, PCD, XYZ) read into
metres, with the units resolved (given, or detected when the numbers can only be millimetres)."""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .clouds import check_ply_complete, ply_elements, read_cloud

MESH_SUFFIXES = {".ply", ".obj", ".stl", ".off", ".glb", ".gltf"}
CLOUD_ONLY_SUFFIXES = {".pcd", ".xyz", ".xyzn", ".pts"}
MODEL_SUFFIXES = MESH_SUFFIXES | CLOUD_ONLY_SUFFIXES
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
# An object wider than this many "metres" is certainly in mm (table-top and warehouse objects are < 3 m).
MM_DETECT_EXTENT = 3.0
# sizes (largest extent, m) of the objects pcdet is for; outside, "auto" units are refused as unclear
PLAUSIBLE_SIZE_M = (0.002, 3.0)


class UnitsWarning(UserWarning):
    """A model's size suggests other units than the ones it was loaded with."""


@dataclass
class Geometry:
    """A model file's geometry in metres: vertices (V, 3), faces (F, 3) or None (point cloud), per-vertex
    normals (V, 3) or None, the scale applied to the file's numbers, notes about units, and per-vertex colours
    (V, 3) in [0, 1] or None (a mesh's vertex colours, a textured mesh's texture sampled at its vertices, or a
    cloud's colours)."""

    vertices: np.ndarray
    faces: np.ndarray | None
    normals: np.ndarray | None
    scale: float
    notes: list[str]
    colors: np.ndarray | None = None


def _mesh_colours(geom) -> np.ndarray | None:
    """(V, 3) colours in [0, 1] of a trimesh mesh's vertices: its vertex colours, or its texture sampled at the
    vertices' UVs; None when it has neither (trimesh's default grey is not a colour)."""
    visual = getattr(geom, "visual", None)
    kind = getattr(visual, "kind", None)
    try:
        if kind == "texture":
            visual = visual.to_color()
        elif kind != "vertex":
            return None
        cols = np.asarray(visual.vertex_colors)
    except Exception:  # a texture trimesh cannot sample (no image, no UVs): the mesh is used without colour
        return None
    if cols.ndim != 2 or len(cols) != len(geom.vertices) or cols.shape[1] < 3:
        return None
    return cols[:, :3].astype(np.float64) / 255.0


def _read_geometry(path: Path):
    """(vertices (V,3), faces (F,3) or None, normals (V,3) or None, colours (V,3) in [0, 1] or None) in file
    units."""
    suffix = path.suffix.lower()
    if suffix in CLOUD_ONLY_SUFFIXES or (suffix == ".ply" and not ply_elements(path).get("face", 0)):
        cd = read_cloud(path)  # a scanned cloud: the cloud reader is faster (and checks the file is whole)
        return cd.points, None, cd.normals, cd.colors
    import trimesh  # meshes only: its import costs a few tenths of a second

    if suffix == ".ply":
        check_ply_complete(path)
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
        return np.asarray(geom.vertices, float), np.asarray(geom.faces, np.int64), None, _mesh_colours(geom)
    verts = np.asarray(getattr(geom, "vertices", np.zeros((0, 3))), float)
    normals = None
    if suffix == ".ply" and len(verts):  # point-only PLY: take its normals if it has them
        normals = read_cloud(path, keep_invalid=True).normals
    return verts, None, normals, None


def resolve_scale(verts: np.ndarray, units, path: Path, notes: list[str]) -> float:
    """The factor from file units to metres: ``units`` ("m", "cm", "mm" or a number), or with "auto"/None 0.001
    when the model is over 3 units wide (noted in ``notes``), else 1. A size that no object pcdet looks for has
    (under 2 mm or over 3 m, after reading) is refused in "auto" mode, since it means the units are not what
    they seem: give ``units`` to read such a model anyway. Forced units that make the model over 3 m wide are
    warned about (``UnitsWarning``)."""
    extent = float((verts.max(axis=0) - verts.min(axis=0)).max())
    if units in (None, "auto"):
        scale = 0.001 if extent > MM_DETECT_EXTENT else 1.0
        size = extent * scale
        if not PLAUSIBLE_SIZE_M[0] <= size <= PLAUSIBLE_SIZE_M[1]:
            read = "millimetres" if scale == 0.001 else "metres"
            raise InputError(f"model is {extent:.6g} units wide, {_metres(size)} when read as {read}: no object "
                             "pcdet detects is that size, so the units are unclear; give them (--units m, cm or "
                             "mm; units= in Python) to read it anyway", path)
        if scale == 0.001:
            notes.append(f"{path.name}: {extent:.0f} units wide, read as millimetres")
        return scale
    scale = UNITS.get(units) if isinstance(units, str) else float(units)
    if scale is None:
        raise InputError(f"unknown units {units!r}; use one of {sorted(UNITS)}, 'auto' or a number", path)
    if extent * scale > MM_DETECT_EXTENT:
        warnings.warn(f"{path}: model is {extent * scale:.1f} m wide when read as {units}, larger than any object "
                      "pcdet detects; check the units", UnitsWarning, stacklevel=3)
    return scale


def _metres(x: float) -> str:
    return f"{x * 1000:.3g} mm" if x < 1 else f"{x:.3g} m"


def load_geometry(path, units="auto") -> Geometry:
    """Read a mesh or point-cloud model file, validate it and convert it to metres."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: model file not found")
    if path.suffix.lower() not in MODEL_SUFFIXES:
        raise InputError(f"unknown model format {path.suffix!r}; expected one of {sorted(MODEL_SUFFIXES)}", path)
    verts, faces, vnormals, colours = _read_geometry(path)
    if faces is None:
        fin = np.isfinite(verts).all(axis=1)
        verts = verts[fin]
        vnormals = vnormals[fin] if vnormals is not None else None
        colours = colours[fin] if colours is not None and len(colours) == len(fin) else None
    if colours is not None and np.ptp(colours, axis=0).max() < 2 / 255:
        colours = None  # one colour everywhere is a paint (a tool's default), not the object's appearance
    elif not np.isfinite(verts).all():
        raise InputError("mesh has non-finite vertex coordinates", path)
    if len(verts) < 3:
        raise InputError(f"model has {len(verts)} points; at least 3 are needed", path)
    notes: list[str] = []
    scale = resolve_scale(verts, units, path, notes)
    return Geometry(verts * scale, faces, vnormals, scale, notes, colours)


def as_geometry(source, units="auto", name: str = "input") -> Geometry:
    """A model or scan given in any form pcdet takes, as a ``Geometry`` in metres: a file path (``load_geometry``),
    an (N, 3) array of points, an open3d ``PointCloud`` or ``TriangleMesh``, a trimesh ``Trimesh`` or
    ``PointCloud``, or a ``Geometry`` (already in metres: returned as it is, ``units`` aside; the way to give a
    cloud's normals, oriented as the caller knows them, without open3d). ``name`` stands for the input in messages
    when it is not a file."""
    if isinstance(source, (str, Path)):
        return load_geometry(source, units)
    if isinstance(source, Geometry):
        return source
    verts, faces, normals = _in_memory(source, name)
    if faces is None:
        fin = np.isfinite(verts).all(axis=1)
        if not fin.all():
            verts, normals = verts[fin], (normals[fin] if normals is not None else None)
    elif not np.isfinite(verts).all():
        raise InputError(f"{name}: mesh has non-finite vertex coordinates")
    if len(verts) < 3:
        raise InputError(f"{name}: {len(verts)} finite points; at least 3 are needed")
    notes: list[str] = []
    scale = resolve_scale(verts, units, Path(name), notes)
    return Geometry(verts * scale, faces, normals, scale, notes)  # a copy: the caller's array stays theirs


def _in_memory(source, name: str):
    """(vertices (V, 3), faces (F, 3) or None, normals (V, 3) or None) of an in-memory geometry."""
    if isinstance(source, (np.ndarray, list, tuple)):
        a = np.asarray(source, dtype=float)
        if a.ndim != 2 or a.shape[1] != 3:
            raise InputError(f"{name}: points must be an (N, 3) array, got shape {a.shape}")
        return a, None, None
    if hasattr(source, "points") and hasattr(source, "has_normals"):  # open3d PointCloud
        pts = np.asarray(source.points, float)
        return pts, None, (np.asarray(source.normals, float) if source.has_normals() else None)
    if hasattr(source, "triangles") and hasattr(source, "vertices") and hasattr(source, "has_triangles"):
        faces = np.asarray(source.triangles, np.int64)  # open3d TriangleMesh
        return np.asarray(source.vertices, float), (faces if len(faces) else None), None
    if type(source).__module__.startswith("trimesh"):
        faces = getattr(source, "faces", None)
        faces = np.asarray(faces, np.int64) if faces is not None and len(faces) else None
        return np.asarray(source.vertices, float), faces, None
    raise InputError(f"{name}: expected a file path, an (N, 3) array, an open3d PointCloud or TriangleMesh, or "
                     f"a trimesh object; got {type(source).__name__}")
