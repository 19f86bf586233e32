"""Depth rendering on the CPU: meshes with open3d's RaycastingScene, point models by z-buffer splatting.

Pixel (u, v) samples the ray through (u, v) itself (OpenCV convention, as ``Camera.backproject``), so a
rendered depth back-projects onto the surface that produced it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import label, minimum_filter

from .align import transform
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
        v = transform(T, np.asarray(verts, float))
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


def mesh_depth_at(camera: Camera, vertices: np.ndarray, faces: np.ndarray, T_cam_mesh: np.ndarray,
                  pixels: np.ndarray) -> np.ndarray:
    """(N,) float32 depth (m, 0 where the ray misses) of one mesh at ``pixels`` (N,) flat indices only:
    no full-image buffers, for the many small renders of verification."""
    from ._o3d import o3d

    scene = o3d.t.geometry.RaycastingScene()
    v = transform(T_cam_mesh, np.asarray(vertices, float))
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(np.asarray(faces, dtype=np.uint32)))
    t = scene.cast_rays(o3d.core.Tensor(camera_rays(camera, pixels)))["t_hit"].numpy()
    return np.where(np.isfinite(t), t, 0).astype(np.float32)


class MeshCaster:
    """A mesh's ray-casting structure, built once in the mesh's own frame; ``depth_at`` moves the camera's rays
    into that frame instead of moving (and re-indexing) the mesh for every pose. Same depths as
    ``mesh_depth_at``."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        from ._o3d import o3d

        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(np.asarray(vertices, np.float32)),
                                  o3d.core.Tensor(np.asarray(faces, dtype=np.uint32)))

    @staticmethod
    def _rays(camera: Camera, T_cam_mesh: np.ndarray, pixels: np.ndarray) -> np.ndarray:
        """(N, 6) float32 rays of flat ``pixels`` in the mesh frame, for the mesh at ``T_cam_mesh``."""
        d = camera_rays(camera, pixels)[:, 3:].astype(np.float64)
        R, t = T_cam_mesh[:3, :3], T_cam_mesh[:3, 3]
        rays = np.empty((len(d), 6), np.float32)
        rays[:, :3] = -R.T @ t  # the camera centre in the mesh frame
        rays[:, 3:] = d @ R  # directions rotated into the mesh frame (lengths kept: t_hit is z)
        return rays

    def _cast(self, camera: Camera, T_cam_mesh: np.ndarray, pixels: np.ndarray) -> dict:
        from ._o3d import o3d

        return self._scene.cast_rays(o3d.core.Tensor(self._rays(camera, T_cam_mesh, pixels)))

    def depth_at(self, camera: Camera, T_cam_mesh: np.ndarray, pixels: np.ndarray) -> np.ndarray:
        """(N,) float32 depth (m, 0 where the ray misses) of the mesh at ``T_cam_mesh`` at flat ``pixels``."""
        return self.depth_at_poses(camera, [T_cam_mesh], [pixels])[0]

    def depth_at_poses(self, camera: Camera, poses, pixels: list[np.ndarray]) -> list[np.ndarray]:
        """``depth_at`` for B poses (each (4, 4)) at their own flat ``pixels`` (B arrays), all rays cast in one
        call: each ray is traced on its own, so the depths are those of B calls, without B calls' overhead (the
        first look at a frame's raw poses casts a few hundred rays for each of several hundred poses)."""
        from ._o3d import o3d

        if sum(len(p) for p in pixels) == 0:
            return [np.zeros(0, np.float32) for _ in pixels]
        rays = np.concatenate([self._rays(camera, T, p) for T, p in zip(poses, pixels)])
        hit = self._scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        depth = np.where(np.isfinite(hit), hit, 0).astype(np.float32)
        return np.split(depth, np.cumsum([len(p) for p in pixels])[:-1])

    def cast(self, camera: Camera, T_cam_mesh: np.ndarray, pixels: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At flat ``pixels`` (N,): depth (N,) float32 m (0 where the ray misses), the hit triangle's unit normal
        in the camera frame (N, 3) and its index (N,) int64 (-1 where the ray misses)."""
        ans = self._cast(camera, T_cam_mesh, pixels)
        hit = ans["t_hit"].numpy()
        ok = np.isfinite(hit)
        normals = ans["primitive_normals"].numpy().astype(np.float64) @ T_cam_mesh[:3, :3].T
        ids = np.where(ok, ans["primitive_ids"].numpy().astype(np.int64), -1)
        return np.where(ok, hit, 0).astype(np.float32), normals, ids


def render_points(camera: Camera, points_cam: np.ndarray, spacing: float) -> np.ndarray:
    """Z-buffer (N, 3) camera-frame points into an (H, W) float32 depth image (0 where empty), each point
    splatted over a square of about ``spacing`` metres so that sampled surfaces render without holes; the outer
    outline stays at the outermost points' pixels."""
    p = np.asarray(points_cam, float)
    p = p[p[:, 2] > 1e-6]
    out = np.zeros((camera.height, camera.width), np.float32)
    if len(p) == 0:
        return out
    uv = np.rint(camera.project(p)).astype(np.int64)
    ok = camera.in_image(uv)
    if not ok.any():
        return out
    uv, z = uv[ok], p[ok, 2]
    r = int(np.ceil(camera.fx * spacing / max(float(np.median(z)), 1e-3)))
    r = min(max(r, 1), 9)
    # work in the points' bounding box (plus the splat margin) only
    u0, v0 = np.maximum(uv.min(axis=0) - r, 0)
    u1, v1 = np.minimum(uv.max(axis=0) + r + 1, [camera.width, camera.height])
    w, h = u1 - u0, v1 - v0
    buf = np.full(w * h, np.inf)
    np.minimum.at(buf, (uv[:, 1] - v0) * w + (uv[:, 0] - u0), z)
    buf = buf.reshape(h, w)
    if r > 1:
        buf = minimum_filter(buf, size=r)
        # the splats fill the gaps between samples but draw the outline half a splat wider all round, where a pose
        # of the right size then sees through: the outer outline goes back to the outermost samples. The empty
        # pixels connected to the buffer's edge are the outside; what is not outside is eroded by the same square
        # (reflected: for an even r its origin moves back by one pixel), as a separable minimum filter
        lab, n = label(~np.isfinite(buf))
        outside = np.zeros(n + 1, bool)
        outside[np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]])] = True
        outside[0] = False  # label 0: the filled pixels
        inner = ~outside[lab]
        outline = minimum_filter(inner.view(np.uint8), size=r, mode="constant", cval=1, origin=r % 2 - 1)
        buf[outline == 0] = np.inf
    buf[~np.isfinite(buf)] = 0
    out[v0:v1, u0:u1] = buf
    return out
