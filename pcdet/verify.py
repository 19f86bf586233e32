"""Hypothesis verification against the measured depth, and conflict resolution between hypotheses.

The model is rendered at its pose (meshes with open3d's RaycastingScene, point models by z-buffer splatting),
so self-occlusion is exact. Each pixel the model would cover is compared with the measured depth d against the
rendered depth r (tolerance tau):
  supported  |d - r| <= tau       the measurement agrees with the model's surface;
  occluded   d < r - tau          something in front hides the model there (no evidence either way);
  violation  d > r + tau          the sensor sees through where the model's surface would be;
  unknown    d == 0               no measurement (weakly against: sensors drop pixels, but not whole objects).
When the scene's supporting plane is known, model samples more than tau below it are physically impossible
(an object cannot sink into its support); their share multiplies the score down.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .align import transform
from .camera import Camera
from .cloud import Plane
from .errors import ConfigError
from .model import ObjectModel
from .params import check_positive, check_range, param
from .render import MeshCaster, mesh_depth_at, render_meshes, render_points


@dataclass(frozen=True)
class VerifyConfig:
    """Verification against the depth and the choice of detections (global or by threshold)."""

    depth_tolerance: float = param(0.008, "m; rendered vs measured depth agreement")
    min_score: float = param(0.35, "acceptance threshold on the verification score")
    min_supported: int = param(40, "pixels that must agree with the model")
    max_violation: float = param(0.25, "share of see-through pixels allowed")
    conflict_overlap: float = param(0.3, "share of a detection's pixels that may be claimed by a better one")
    prefilter: float = param(0.15, "score a raw hypothesis needs before ICP")
    max_penetration: float = param(0.05, "share of model samples allowed below the supporting plane")
    selection: str = param("global", "threshold: all accepted, greedy conflicts; global: the accepted subset "
                                     "that best explains the scene")
    explain_radius: float = param(0.006, "m; global: a scene point within this of a model sample is explained "
                                         "by it")
    clutter_radius: float = param(0.015, "m; global: unexplained scene points this close to explained ones are "
                                         "clutter")
    duplicate_weight: float = param(1.0, "global: cost of each scene point explained twice")
    clutter_weight: float = param(5.0, "global: cost of each clutter point no chosen detection explains")
    violation_weight: float = param(1.0, "global: cost of see-through evidence (in scene points)")
    size_ring: float = param(0.003, "m; look-alikes: of two sizes of one shape on one spot, the one whose outline "
                                    "fits is kept, counting against each the pixels this far outside its outline "
                                    "where the measured surface runs on (size_fit)")
    size_margin: float = param(0.05, "look-alikes: before the outlines are compared, a size whose fitted scale "
                                     "(refine.scale_fit) is further from 1 than another's on its spot by more than "
                                     "this (in log scale) loses to it, where the view fixes both scales (0: off)")

    def __post_init__(self):
        check_positive(self, "depth_tolerance", "min_supported", "explain_radius", "clutter_radius", "size_ring")
        for n in ("min_score", "max_violation", "conflict_overlap", "prefilter", "max_penetration"):
            check_range(self, n, 0, 1)
        if self.selection not in ("threshold", "global"):
            raise ConfigError(f"VerifyConfig.selection must be 'threshold' or 'global', got {self.selection!r}")
        for n in ("duplicate_weight", "clutter_weight", "violation_weight", "size_margin"):
            if getattr(self, n) < 0:
                raise ConfigError(f"VerifyConfig.{n} must be >= 0, got {getattr(self, n)}")


@dataclass
class Verification:
    """score = supported / (supported + violations + occluded / 2 + unknown / 4) x (1 - penetration)^2, in [0, 1];
    fitness = supported / (supported + violations); visible_fraction = supported / rendered pixels;
    penetration = share of model samples below the supporting plane (0 without a plane).
    support : (S,) flat pixel indices of the supported pixels (what this hypothesis claims)."""

    score: float
    fitness: float
    visible_fraction: float
    n_rendered: int
    n_supported: int
    n_occluded: int
    n_violations: int
    penetration: float
    support: np.ndarray

    def accepted(self, cfg: VerifyConfig) -> bool:
        """Whether the pose passes the per-pose checks: enough supported pixels, score, see-through share,
        penetration."""
        return (self.n_supported >= cfg.min_supported and self.score >= cfg.min_score
                and self.n_violations <= cfg.max_violation * max(self.n_supported + self.n_violations, 1)
                and self.penetration <= cfg.max_penetration)


def bbox_pixels(camera: Camera, pts_cam: np.ndarray, stride: int = 1, margin: int = 1) -> np.ndarray | None:
    """Flat pixel indices of the image box around the projection of ``pts_cam`` (N, 3) (points in front of the
    camera only), grown by ``margin`` pixels and clipped to the image; every ``stride``-th row and column. None
    when the box misses the image."""
    front = pts_cam[:, 2] > 1e-3
    if not front.any():
        return None
    uv = camera.project(pts_cam[front])
    u0, v0 = np.floor(uv.min(axis=0)).astype(int) - margin
    u1, v1 = np.ceil(uv.max(axis=0)).astype(int) + margin
    u0, v0 = max(u0, 0), max(v0, 0)
    u1, v1 = min(u1, camera.width - 1), min(v1, camera.height - 1)
    if u0 > u1 or v0 > v1:
        return None
    return (np.arange(v0, v1 + 1, stride)[:, None] * camera.width + np.arange(u0, u1 + 1, stride)).reshape(-1)


def render_model(model: ObjectModel, T_cam_model: np.ndarray, camera: Camera, *, spacing: float = 0.004,
                 stride: int = 1) -> np.ndarray:
    """(H, W) float32 depth (m) of the model alone at ``T_cam_model``; 0 off the model (and, for meshes with
    ``stride`` > 1, off every stride-th row and column). Point models are splatted at ``spacing`` m."""
    pts = transform(T_cam_model, model.points)
    if model.is_mesh:
        pix = bbox_pixels(camera, pts, stride)
        if pix is None:
            return np.zeros((camera.height, camera.width), np.float32)
        return render_meshes(camera, [(model.vertices, model.faces, T_cam_model)], pix).depth
    return render_points(camera, pts, spacing)


def _mesh_depth(model: ObjectModel, T_cam_model: np.ndarray, camera: Camera, pixels: np.ndarray,
                caster: MeshCaster | None) -> np.ndarray:
    """(P,) depth (m, 0 where the ray misses) of the mesh ``model`` at ``T_cam_model`` at the flat ``pixels`` (P,),
    with the mesh's ray-casting structure when given."""
    if not len(pixels):
        return np.zeros(0, np.float32)
    if caster is not None:
        return caster.depth_at(camera, T_cam_model, pixels)
    return mesh_depth_at(camera, model.vertices, model.faces, T_cam_model, pixels)


def _score(supported: int, violations: int, occluded: int, unknown: int, penetration: float) -> float:
    """The verification score from pixel counts (see ``Verification``)."""
    return supported / max(supported + violations + 0.5 * occluded + 0.25 * unknown, 1.0) * (1.0 - penetration) ** 2


def verify(model: ObjectModel, T_cam_model: np.ndarray, depth: np.ndarray, camera: Camera, cfg: VerifyConfig, *,
           spacing: float = 0.004, plane: Plane | None = None, stride: int = 1,
           caster: MeshCaster | None = None, hull: np.ndarray | None = None) -> Verification:
    """Compare ``model`` rendered at ``T_cam_model`` with measured ``depth`` (H, W) float32 metres; with the
    scene's supporting ``plane``, also measure how much of the model would sink into it. ``stride`` > 1 looks
    at every stride-th row and column only (a quick first look; pixel counts shrink by stride^2).
    ``caster``: the mesh's ray-casting structure (``render.MeshCaster``); ``hull``: see ``verify_poses``."""
    return verify_poses(model, [T_cam_model], depth, camera, cfg, spacing=spacing, plane=plane, stride=stride,
                        caster=caster, hull=hull)[0]


def verify_poses(model: ObjectModel, poses, depth: np.ndarray, camera: Camera, cfg: VerifyConfig, *,
                 spacing: float = 0.004, plane: Plane | None = None, stride: int = 1,
                 caster: MeshCaster | None = None, hull: np.ndarray | None = None) -> list[Verification]:
    """``verify`` of each of ``poses`` (B poses (4, 4) of one model), in order. With a ``caster``, the rays of all
    B poses are cast in one call (``MeshCaster.depth_at_poses``): the same depths as one call per pose.

    hull : optional (H, 3) vertices of the convex hull of ``model.points`` (``cloud.hull_vertices``). The image
        box a mesh is cast in and the samples below the plane are then found on the hull alone where it decides
        them, with the same result: where every hull vertex lies in front of the camera, the extreme projections
        of the samples are those of hull vertices (x / z is linear-fractional, so its extremes over a polytope lie
        at vertices); where none lies more than the tolerance below the plane, no sample does.
    """
    tau = cfg.depth_tolerance
    placed_hull = [None if hull is None else transform(T, hull) for T in poses]
    if model.is_mesh:
        boxes = [_image_box(model, T, H, camera, stride) for T, H in zip(poses, placed_hull)]
        if caster is not None:
            depths = caster.depth_at_poses(camera, poses, boxes)
        else:
            depths = [_mesh_depth(model, T, camera, box, None) for T, box in zip(poses, boxes)]
        seen = [(box[rv > 0], rv[rv > 0]) for box, rv in zip(boxes, depths)]
    else:
        seen = []
        for T in poses:
            r = render_model(model, T, camera, spacing=spacing, stride=stride).reshape(-1)
            pix = np.flatnonzero(r > 0)
            seen.append((pix, r[pix]))
    out = []
    for T, H, (pix, rv) in zip(poses, placed_hull, seen):
        dv = depth.reshape(-1)[pix]
        known = dv > 0
        sup = known & (np.abs(dv - rv) <= tau)
        occ = known & (dv < rv - tau)
        vio = known & (dv > rv + tau)
        ns, no, nv = int(sup.sum()), int(occ.sum()), int(vio.sum())
        pen = 0.0
        if plane is not None and (H is None or (H @ plane.normal + plane.offset).min() < -tau):
            pen = float(np.mean(transform(T, model.points) @ plane.normal + plane.offset < -tau))
        score = _score(ns, nv, no, int((~known).sum()), pen)
        out.append(Verification(score, ns / max(ns + nv, 1), ns / max(len(pix), 1), len(pix), ns, no, nv, pen,
                                pix[sup]))
    return out


def _image_box(model: ObjectModel, T_cam_model: np.ndarray, placed_hull: np.ndarray | None, camera: Camera,
               stride: int) -> np.ndarray:
    """(P,) flat pixel indices of the image box of ``model``'s samples at ``T_cam_model`` (``bbox_pixels``), read
    off its placed hull vertices where all of them are in front of the camera; empty when the box misses."""
    if placed_hull is not None and np.all(placed_hull[:, 2] > 1e-3):
        box = bbox_pixels(camera, placed_hull, stride)
    else:
        box = bbox_pixels(camera, transform(T_cam_model, model.points), stride)
    return np.zeros(0, np.int64) if box is None else box


def continuing_surface(model: ObjectModel, T_cam_model: np.ndarray, depth: np.ndarray, camera: Camera, *,
                       tolerance: float, ring: float, spacing: float = 0.004, caster: MeshCaster | None = None) -> int:
    """Pixels within ``ring`` m (at the model's median depth) outside the outline of ``model`` rendered at
    ``T_cam_model`` where the measured ``depth`` (H, W) m lies within ``tolerance`` m of the model's depth at the
    nearest pixel of its outline: the measured surface runs on past the model's edge. A model too small for the
    object it sits on has such a rim all round; a model of the right size mostly sees the background step away, an
    occluder or its support there."""
    P = transform(T_cam_model, model.points)
    front = P[:, 2] > 1e-3
    if not front.any():
        return 0
    px = max(1, int(round(ring * camera.fx / float(np.median(P[front, 2])))))
    box = bbox_pixels(camera, P, 1, margin=px + 1)
    if box is None:
        return 0
    if model.is_mesh:
        rv = _mesh_depth(model, T_cam_model, camera, box, caster)
    else:
        rv = render_points(camera, P, spacing).reshape(-1)[box]
    rows, cols = np.divmod(box, camera.width)
    shape = (rows[-1] - rows[0] + 1, cols[-1] - cols[0] + 1)  # the box is a full rectangle, row by row
    R, D = rv.reshape(shape), depth.reshape(-1)[box].reshape(shape)
    inside = R > 0
    if not inside.any():
        return 0
    rim = ndimage.binary_dilation(inside, iterations=px) & ~inside
    _, (iy, ix) = ndimage.distance_transform_edt(~inside, return_indices=True)
    return int((rim & (D > 0) & (np.abs(D - R[iy, ix]) <= tolerance)).sum())


def size_fit(v: Verification, continuing: int) -> float:
    """The verification score with ``continuing`` pixels (``continuing_surface``) counted against the pose as
    see-through pixels are: a model too large sees through past the object's edge, one too small leaves the
    object's surface running on past its own. In [0, 1]."""
    unknown = v.n_rendered - v.n_supported - v.n_occluded - v.n_violations
    return _score(v.n_supported, v.n_violations + continuing, v.n_occluded, unknown, v.penetration)


def resolve_conflicts(order: list[int], supports: list[np.ndarray], max_overlap: float, n_pixels: int) -> list[int]:
    """Greedy: walk ``order`` (best first) and keep an item unless more than ``max_overlap`` of its supported
    pixels (flat indices < ``n_pixels``) are already claimed by a kept one. Returns the kept items, in order."""
    claimed = np.zeros(n_pixels, bool)
    kept = []
    for i in order:
        s = supports[i]
        if len(s) == 0:
            continue
        if claimed[s].mean() <= max_overlap:
            kept.append(i)
            claimed[s] = True
    return kept
