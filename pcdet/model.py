"""Object models: surface samples with outward normals, keypoints, FPFH and LRFs from rendered views, and the
diameter; built from a mesh or a point-cloud file (``build_model``). ``model_cache.load_model`` keeps them on
disk and ``library.ModelLibrary`` holds a set of them."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .blas import on_one_blas_thread
from .cloud import diameter as cloud_diameter
from .cloud import estimate_normals, outward_normals, voxel_downsample
from .colour import surface_colours
from .errors import InputError
from .io.models import as_geometry
from .model_views import DescriptorParams, view_features


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
    kp_colors : (K, 3) float32 colour in [0, 1] of the surface around each keypoint (from the file's vertex
        colours or texture), or None when the model has no colour.
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
    kp_colors: np.ndarray | None = None

    @property
    def is_mesh(self) -> bool:
        """Whether the model has triangles (a mesh) rather than points only."""
        return self.faces is not None and len(self.faces) > 0

    def __repr__(self) -> str:
        kind = f"mesh of {len(self.faces)} faces" if self.is_mesh else "point cloud"
        return (f"ObjectModel({self.name!r}, obj_id={self.obj_id}, {kind}, diameter {self.diameter * 1000:.1f} mm, "
                f"{len(self.points)} samples, {len(self.kp_points)} keypoints)")


@on_one_blas_thread
def build_model(source, cfg: DescriptorParams, *, units="auto", obj_id: int = 0, name: str | None = None,
                seed: int = 0) -> ObjectModel:
    """Compute a model's samples, normals, keypoints and FPFH (no cache). ``source``: a model file, or an
    in-memory mesh or cloud (an (N, 3) array, an open3d or trimesh geometry; see ``io.models.as_geometry``),
    which then needs a ``name``. BLAS runs on one thread meanwhile (``pcdet.blas``)."""
    in_memory = not isinstance(source, (str, Path))
    path = Path(name or "model") if in_memory else Path(source)
    g = as_geometry(source, units, name=str(path))
    verts, faces, vnormals = g.vertices, g.faces, g.normals
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
            nrm = outward_normals(pts, pp.normal_radius, pp.normal_max_nn)
    if len(pts) < 10:
        raise InputError(f"model has only {len(pts)} samples at voxel {pp.voxel} m: is it tiny, or in the "
                         "wrong units?", path)
    vv = verts if faces is not None else None
    diameter = cloud_diameter(verts if vv is not None else pts)  # a mesh's vertices give the exact value
    kpp, kpn, feats, lrfs = view_features(pts, nrm, cfg, diameter=diameter, vertices=vv, faces=faces)
    if len(kpp) < 3:
        raise InputError("no view of the model yields keypoints: is it flat, tiny, or in the wrong units?", path)
    colours = None
    if g.colors is not None:
        colours = surface_colours(kpp, verts, g.colors).astype(np.float32)
    return ObjectModel(name or path.stem, int(obj_id), "" if in_memory else str(path), pts, nrm, kpp, kpn, feats,
                       lrfs, diameter, g.scale, vv, faces, g.notes, colours)
