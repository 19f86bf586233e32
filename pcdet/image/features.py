"""Feature points as Liu and Wang find them: edge detection, Hough lines, and the pairwise intersections of the
lines that lie on an edge."""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from .hough import Line, edge_map, hough_lines


def intersect(a: Line, b: Line) -> np.ndarray | None:
    """(x, y) where two lines ``x cos t - y sin t = d`` cross, or None when they are parallel."""
    ta, tb = np.radians(a.theta_deg), np.radians(b.theta_deg)
    M = np.array([[np.cos(ta), -np.sin(ta)], [np.cos(tb), -np.sin(tb)]])
    if abs(np.linalg.det(M)) < 1e-9:
        return None
    return np.linalg.solve(M, [a.d, b.d])


def line_intersections(lines: list[Line], edges: np.ndarray, tolerance: float = 2.0, min_angle_deg: float = 15.0,
                       merge: float = 3.0) -> np.ndarray:
    """(P, 2) intersections (x, y) of every pair of ``lines`` crossing at ``min_angle_deg`` or more, inside the
    image and within ``tolerance`` px of an edge pixel of ``edges`` (H, W); points closer than ``merge`` px are
    merged (their mean). Row order: by y, then x."""
    edges = np.asarray(edges, bool)
    H, W = edges.shape
    dist = ndimage.distance_transform_edt(~edges)
    pts = []
    for i in range(len(lines)):
        for j in range(i + 1, len(lines)):
            da = abs((lines[i].theta_deg - lines[j].theta_deg + 90.0) % 180.0 - 90.0)
            if da < min_angle_deg:
                continue
            p = intersect(lines[i], lines[j])
            if p is None or not (0 <= p[0] <= W - 1 and 0 <= p[1] <= H - 1):
                continue
            if dist[int(round(p[1])), int(round(p[0]))] <= tolerance:
                pts.append(p)
    merged: list[list[np.ndarray]] = []
    for p in pts:
        for group in merged:
            if np.linalg.norm(np.mean(group, axis=0) - p) < merge:
                group.append(p)
                break
        else:
            merged.append([p])
    out = np.array([np.mean(g, axis=0) for g in merged]).reshape(-1, 2)
    return out[np.lexsort((out[:, 0], out[:, 1]))] if len(out) else out


def feature_points(image, threshold: float = 0.2, max_lines: int = 20, min_votes: float | None = None,
                   tolerance: float = 2.0) -> tuple[np.ndarray, list[Line]]:
    """Edge map, Hough lines and their intersections on edges: returns (points (P, 2) x, y; the lines). A bool
    ``image`` is taken as the edge map itself (a line drawing)."""
    im = np.asarray(image)
    if im.dtype == bool:
        edges = im
        lines = hough_lines(im.astype(float), edges=edges, max_lines=max_lines, min_votes=min_votes)
    else:
        edges, _, _ = edge_map(im, threshold)
        lines = hough_lines(im, threshold=threshold, max_lines=max_lines, min_votes=min_votes)
    return line_intersections(lines, edges, tolerance), lines
