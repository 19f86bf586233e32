"""A library model as the detector uses it: the ``ObjectModel`` plus what the pipeline derives from it once
(the sparser samples ICP moves, the point Hough votes for, the descriptor index)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .cloud import hull_vertices, voxel_downsample
from .colour import chromaticity
from .model import ObjectModel
from .render import MeshCaster


@dataclass
class PreparedModel:
    """model : the object; index : its position in the library (hypotheses name it);
    icp_points, icp_normals : (P, 3) samples and outward normals (model frame, m) that ICP moves;
    reference : (3,) the model point Hough votes are cast for (m); descriptor_tree : KD-tree over
    ``model.features``; caster : the mesh's ray-casting structure for verification (None for point models);
    colours : (K, 2) chromaticity of the keypoints (``colour.chromaticity``), None when the model has no colour;
    hull : (H, 3) the samples (``model.points``) on their convex hull, which verification places instead of all
    samples where they decide its image box and its depth below the plane (``verify.verify_poses``)."""

    model: ObjectModel
    index: int
    icp_points: np.ndarray
    icp_normals: np.ndarray
    reference: np.ndarray
    descriptor_tree: cKDTree
    caster: MeshCaster | None = None
    colours: np.ndarray | None = None
    hull: np.ndarray | None = None

    @classmethod
    def build(cls, model: ObjectModel, index: int, *, icp_spacing: float) -> "PreparedModel":
        """ICP samples on a grid of ``icp_spacing`` m (far fewer than verification needs; the shape is kept);
        the Hough reference is the centre of the model's bounding box."""
        p, n, _ = voxel_downsample(model.points, icp_spacing, model.normals, representatives=False)
        caster = MeshCaster(model.vertices, model.faces) if model.is_mesh else None
        colours = chromaticity(model.kp_colors) if model.kp_colors is not None else None
        return cls(model, index, p, n, (model.points.max(0) + model.points.min(0)) / 2, cKDTree(model.features),
                   caster, colours, hull_vertices(model.points))
