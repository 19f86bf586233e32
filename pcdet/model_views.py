"""Model descriptors as a sensor sees the model: keypoints, normals, FPFH and LRFs computed on rendered
partial views, exactly as for a scene (whole-surface FPFH mixes in faces that no single view sees)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .align import transform
from .camera import Camera
from .cloud import estimate_normals
from .features import FeatureConfig, fpfh
from .keypoints import KeypointConfig, select_keypoints
from .lrf import shot_lrf
from .params import check_positive, param
from .preprocess import PreprocessConfig
from .render import render_meshes, render_points


@dataclass(frozen=True)
class ModelConfig:
    """How model descriptors are made: from ``views`` rendered partial views at ``view_distance`` m."""

    views: int = param(30, "rendered partial views per model for its descriptors")
    view_distance: float = param(0.7, "m; distance of those virtual cameras from the model")
    view_noise: float = param(0.0015, "m; standard deviation of depth noise added along the rays of each rendered "
                                   "view before its normals and descriptors are computed, so that they look like "
                                   "a real sensor's (0: clean views)")

    def __post_init__(self):
        check_positive(self, "views", "view_distance")


class DescriptorParams(Protocol):
    """The parameters that describing a model takes (a ``PipelineConfig`` has them all): sampling and normals
    (``preprocess``), views (``model``), keypoints and descriptors."""

    preprocess: PreprocessConfig
    model: ModelConfig
    keypoints: KeypointConfig
    features: FeatureConfig


def view_directions(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere (Fibonacci lattice), deterministic."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z ** 2)
    a = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([r * np.cos(a), r * np.sin(a), z], axis=1)


def view_features(points: np.ndarray, normals: np.ndarray, cfg: DescriptorParams, *, diameter: float,
                  vertices: np.ndarray | None = None, faces: np.ndarray | None = None):
    """Keypoints, normals, FPFH and LRFs of the model as seen from ``cfg.model.views`` viewpoints.

    points, normals : (N, 3) model samples and outward normals (m); vertices, faces : the mesh, when there is
    one (views are then ray-cast, else the samples are splatted). For each viewpoint (on a sphere of radius
    ``cfg.model.view_distance`` m around the model's centre) the samples that the sensor would see are kept
    (rendered depth agrees, normal faces the camera); normals are re-estimated on that partial cloud and
    oriented to the camera, and FPFH and SHOT frames are computed on it, exactly as for a scene. Returns
    ``(kp_points (K, 3), kp_normals (K, 3), features (K, 33) float32, lrfs (K, 3, 3))`` in the model frame
    (LRF rows NaN where invalid).
    """
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
        pc = transform(T_cam_model, points)
        nc = normals @ R.T
        if vertices is not None:
            depth = render_meshes(cam, [(vertices, faces, T_cam_model)]).depth
        else:
            depth = render_points(cam, pc, pp.voxel)
        uv = np.rint(cam.project(pc)).astype(np.int64)
        inside = cam.in_image(uv)
        vis = np.zeros(len(pc), bool)
        dz = depth[uv[inside, 1], uv[inside, 0]]
        vis[inside] = (dz > 0) & (np.abs(pc[inside, 2] - dz) < pp.voxel)
        vis &= (nc * pc).sum(axis=1) < 0  # facing the camera
        if vis.sum() < 20:
            continue
        vp = pc[vis]
        dp = vp
        if mc.view_noise > 0:  # a sensor's depth noise, so that model descriptors look like a real scene's
            rng = np.random.default_rng(len(out_p) + 7919 * int(vis.sum()))
            dp = vp + vp / np.linalg.norm(vp, axis=1, keepdims=True) * rng.normal(0, mc.view_noise, (len(vp), 1))
        vn = estimate_normals(dp, pp.normal_radius, pp.normal_max_nn)  # toward the camera, as in a scene
        kp = select_keypoints(vp, cfg.keypoints)
        feats = fpfh(dp, vn, kp, cfg.features)
        F, _ = shot_lrf(dp, dp[kp], cfg.features.lrf_support)
        out_p.append((vp[kp] - T_cam_model[:3, 3]) @ R)
        out_n.append(vn[kp] @ R)
        out_f.append(feats)
        out_l.append(F @ R)  # camera-frame axes -> model-frame axes (rows); NaN stays NaN
    if not out_p:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 33), np.float32), np.zeros((0, 3, 3))
    return np.concatenate(out_p), np.concatenate(out_n), np.concatenate(out_f), np.concatenate(out_l)
