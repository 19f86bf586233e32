"""Overlay pictures: each detection's silhouette outline drawn over the colour image (or a colour-mapped depth
image when there is none), with its name and score."""
from __future__ import annotations

import colorsys

import numpy as np
from PIL import Image, ImageDraw
from scipy.ndimage import binary_dilation

from .frame import Frame
from .library import ModelLibrary
from .verify import render_model


def colorize_depth(depth: np.ndarray) -> np.ndarray:
    """(H, W) metres -> (H, W, 3) uint8, near = warm, far = cool, invalid = black."""
    valid = depth > 0
    out = np.zeros((*depth.shape, 3), np.uint8)
    if not valid.any():
        return out
    lo, hi = np.percentile(depth[valid], [2, 98])
    t = np.clip((depth - lo) / max(hi - lo, 1e-6), 0, 1)
    # a simple perceptual-ish ramp: yellow -> red -> purple -> blue
    stops = np.array([[253, 231, 37], [240, 90, 40], [150, 40, 150], [40, 60, 160]], float)
    x = t * (len(stops) - 1)
    i = np.minimum(x.astype(int), len(stops) - 2)
    f = (x - i)[..., None]
    out[:] = (stops[i] * (1 - f) + stops[i + 1] * f).astype(np.uint8)
    out[~valid] = 0
    return out


def _colour(k: int) -> tuple[int, int, int]:
    r, g, b = colorsys.hsv_to_rgb((k * 0.61803398875) % 1.0, 0.9, 1.0)
    return int(r * 255), int(g * 255), int(b * 255)


def overlay(frame: Frame, detections, library: ModelLibrary, spacing: float = 0.004) -> np.ndarray:
    """(H, W, 3) uint8 picture of the detections. ``detections`` carry ``T_cam_model`` in the frame's input
    coordinates (as ``Detector.detect`` returns them)."""
    base = frame.rgb if frame.rgb is not None else colorize_depth(frame.depth)
    img = (base.astype(np.float32) * 0.6).astype(np.uint8)
    T_cam_input = np.linalg.inv(frame.T_input_cam)
    labels = []
    for k, d in enumerate(detections):
        m = library.by_id(d.obj_id)
        mask = render_model(m, T_cam_input @ d.T_cam_model, frame.camera, spacing=spacing) > 0
        if not mask.any():
            continue
        col = np.array(_colour(k), np.uint8)
        img[mask] = (0.55 * img[mask] + 0.45 * col).astype(np.uint8)
        edge = binary_dilation(mask, iterations=2) & ~mask
        img[edge] = col
        ys, xs = np.nonzero(mask)
        labels.append((int(xs.min()), max(int(ys.min()) - 12, 0), f"{d.model} {d.score:.2f}", tuple(col.tolist())))
    pil = Image.fromarray(img)
    draw = ImageDraw.Draw(pil)
    for x, y, text, col in labels:
        w = 6 * len(text) + 4
        draw.rectangle([x, y, x + w, y + 11], fill=(0, 0, 0))
        draw.text((x + 2, y), text, fill=col)
    return np.asarray(pil)
