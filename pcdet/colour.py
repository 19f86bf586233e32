"""Colour at keypoints, as chromaticity: what survives between a model's vertex colours and a sensor's image.

Brightness differs between a model's capture and a scene (lighting, exposure, shading), so only the
chromaticity ``3 * (r, g) / (r + g + b)`` is compared: (1, 1) is grey, whatever its brightness. Pixels and
vertices darker than ``DARK`` have no reliable chromaticity; they are marked unknown (NaN) and never refuse a
match.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .camera import Camera

DARK = 0.08  # mean of r, g, b in [0, 1] below which a colour's chromaticity is noise


def chromaticity(rgb: np.ndarray) -> np.ndarray:
    """(..., 2) float32 chromaticity of (..., 3) colours in [0, 1]; NaN where the colour is darker than ``DARK``."""
    rgb = np.asarray(rgb, np.float64)
    s = rgb.sum(axis=-1, keepdims=True)
    out = 3.0 * rgb[..., :2] / np.maximum(s, 1e-9)
    out[(s[..., 0] / 3) < DARK] = np.nan
    return out.astype(np.float32)


def image_colours(points: np.ndarray, camera: Camera, rgb: np.ndarray, *, window: int = 2) -> np.ndarray:
    """(N, 3) float64 mean colour in [0, 1] of the (2 window + 1)^2 pixels around the projection of each of
    ``points`` (N, 3), camera frame, m; ``rgb`` (H, W, 3) uint8 registered with the depth. Points behind the
    camera get NaN."""
    pts = np.asarray(points, np.float64)
    out = np.full((len(pts), 3), np.nan)
    front = pts[:, 2] > 1e-6
    if not front.any():
        return out
    u, v = np.round(camera.project(pts[front])).astype(np.int64).T
    h, w = rgb.shape[:2]
    acc = np.zeros((len(u), 3))
    for dv in range(-window, window + 1):
        for du in range(-window, window + 1):
            acc += rgb[np.clip(v + dv, 0, h - 1), np.clip(u + du, 0, w - 1)]
    out[front] = acc / ((2 * window + 1) ** 2 * 255.0)
    return out


def surface_colours(points: np.ndarray, vertices: np.ndarray, colours: np.ndarray, *, k: int = 8) -> np.ndarray:
    """(N, 3) mean colour of the ``k`` vertices (V, 3) nearest each of ``points`` (N, 3); ``colours`` (V, 3) in
    [0, 1]."""
    k = min(k, len(vertices))
    _, idx = cKDTree(vertices).query(points, k=k)
    return np.asarray(colours, np.float64)[np.asarray(idx).reshape(len(points), k)].mean(axis=1)


def colour_within(colours: np.ndarray, palette: np.ndarray, gate: float) -> np.ndarray:
    """(N,) bool: which of ``colours`` (N, 2) chromaticities lie within ``gate`` of some colour of ``palette``
    (M, 2). Unknown (NaN) colours pass, and all pass when the palette holds an unknown colour."""
    colours, palette = np.asarray(colours, np.float64), np.asarray(palette, np.float64)
    known = np.isfinite(palette).all(axis=1)
    if not known.all() or len(palette) == 0:
        return np.ones(len(colours), bool)
    out = np.ones(len(colours), bool)
    seen = np.isfinite(colours).all(axis=1)
    if seen.any():
        d, _ = cKDTree(palette).query(colours[seen], distance_upper_bound=gate)
        out[seen] = np.isfinite(d)
    return out
