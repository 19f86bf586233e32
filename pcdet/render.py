"""Depth rendering on the CPU: meshes with open3d's RaycastingScene, point models by z-buffer splatting.

Pixel (u, v) samples the ray through (u, v) itself (OpenCV convention, as ``Camera.backproject``), so a
rendered depth back-projects onto the surface that produced it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import minimum_filter

from .camera import Camera


@dataclass
class Rendering:
    """depth : (H, W) float32 m, 0 where nothing is hit; ids : (H, W) int32 index of the object hit, -1 none;
    normals : (H, W, 3) float32 camera-frame unit normals of the hit surface (zeros where nothing is hit)."""

    depth: np.ndarray
    ids: np.ndarray
    normals: np.ndarray


def camera_rays(camera: Camera, pixels: np.ndarray | None = None) -> np.ndarray:
    """(N, 6) float32 rays (origin 0, direction with z = 1) for flat pixel indices (all pixels when None)."""
    if pixels is None:
        pixels = np.arange(camera.width * camera.height)
    v, u = np.divmod(np.asarray(pixels), camera.width)
    d = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones(len(u))], axis=1)
    return np.concatenate([np.zeros_like(d), d], axis=1).astype(np.float32)


def render_meshes(camera: Camera, meshes: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
                  pixels: np.ndarray | None = None) -> Rendering:
    """Render triangle meshes.

    meshes : list of ``(vertices (V, 3) m, faces (F, 3) int, T_cam_mesh (4, 4))``.
    pixels : optional (N,) flat pixel indices to cast (the rest stay empty), for cheap local renders.
    """
    from ._o3d import o3d

    scene = o3d.t.geometry.RaycastingScene()
    geom_to_obj = {}
    for i, (verts, faces, T) in enumerate(meshes):
        v = np.asarray(verts, float) @ T[:3, :3].T + T[:3, 3]
        gid = scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)),
                                  o3d.core.Tensor(np.asarray(faces, dtype=np.uint32)))
        geom_to_obj[gid] = i
    h, w = camera.height, camera.width
    if pixels is None:
        pixels = np.arange(h * w)
    ans = scene.cast_rays(o3d.core.Tensor(camera_rays(camera, pixels)))
    t = ans["t_hit"].numpy()
    gids = ans["geometry_ids"].numpy().astype(np.int64)
    hit = np.isfinite(t)
    lut = np.full(max(geom_to_obj, default=0) + 2, -1, np.int32)
    for g, i in geom_to_obj.items():
        lut[g] = i
    depth = np.zeros(h * w, np.float32)
    ids = np.full(h * w, -1, np.int32)
    normals = np.zeros((h * w, 3), np.float32)
    depth[pixels[hit]] = t[hit]
    ids[pixels[hit]] = lut[gids[hit]]
    n = ans["primitive_normals"].numpy()[hit]
    n[(n[:, 2] > 0)] *= -1  # face the camera (the ray's direction has +z)
    normals[pixels[hit]] = n
    return Rendering(depth.reshape(h, w), ids.reshape(h, w), normals.reshape(h, w, 3))


def render_points(camera: Camera, points_cam: np.ndarray, spacing: float) -> np.ndarray:
    """Z-buffer (N, 3) camera-frame points into an (H, W) float32 depth image (0 where empty), each point
    splatted over a square of about ``spacing`` metres so that sampled surfaces render without holes."""
    p = np.asarray(points_cam, float)
    p = p[p[:, 2] > 1e-6]
    depth = np.full(camera.height * camera.width, np.inf)
    if len(p):
        uv = np.rint(camera.project(p)).astype(np.int64)
        ok = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
        np.minimum.at(depth, uv[ok, 1] * camera.width + uv[ok, 0], p[ok, 2])
        r = int(np.ceil(camera.fx * spacing / max(float(np.median(p[:, 2])), 1e-3)))
        if r > 1:
            depth = minimum_filter(depth.reshape(camera.height, camera.width), size=min(r, 9)).reshape(-1)
    depth[~np.isfinite(depth)] = 0
    return depth.reshape(camera.height, camera.width).astype(np.float32)
