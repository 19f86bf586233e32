"""Hough transforms: straight lines, circles, arbitrary shapes (the generalised Hough transform), and Hough voting
of oriented keypoint matches.

Images are (H, W) arrays, x to the right (columns), y down (rows). Lines use the polar form of the lecture,

    x cos(t) - y sin(t) = d,        t in [0, 180) degrees, d signed (pixels),

so (cos t, -sin t) is the line's normal. Extensions: with ``use_orientation`` each edge pixel votes only for
angles within ``orientation_window_deg`` of its gradient direction (the gradient is normal to the edge), and
with ``weight_by_magnitude`` a vote weighs the gradient magnitude.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..errors import InputError


def gradients(image) -> tuple[np.ndarray, np.ndarray]:
    """Sobel gradients (gx, gy) of a grey image (float); colour images are averaged to grey first."""
    im = np.asarray(image, float)
    if im.ndim == 3:
        im = im[..., :3].mean(axis=2)
    if im.ndim != 2 or min(im.shape) < 3:
        raise InputError(f"expected a 2D image of at least 3x3 pixels, got shape {np.shape(image)}")
    return ndimage.sobel(im, axis=1), ndimage.sobel(im, axis=0)


def edge_map(image, threshold: float = 0.2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges by gradient magnitude with non-maximum suppression along the gradient (one pixel wide):
    returns (edges (H, W) bool, gx, gy). ``threshold`` is a share of the largest magnitude."""
    gx, gy = gradients(image)
    mag = np.hypot(gx, gy)
    if mag.max() == 0:
        return np.zeros(mag.shape, bool), gx, gy
    ang = (np.round(np.degrees(np.arctan2(gy, gx)) / 45.0).astype(int)) % 4  # 0: x, 1: diagonal, 2: y, 3: anti
    keep = np.zeros(mag.shape, bool)
    pad = np.pad(mag, 1)
    H, W = mag.shape
    for k, (dy, dx) in enumerate(((0, 1), (1, 1), (1, 0), (1, -1))):
        a = pad[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
        b = pad[1 - dy:1 - dy + H, 1 - dx:1 - dx + W]
        keep |= (ang == k) & (mag >= a) & (mag >= b)
    return keep & (mag > threshold * mag.max()), gx, gy


def _peaks(acc: np.ndarray, min_votes: float, size, max_peaks: int, wrap_axis: int | None = None) -> np.ndarray:
    """Indices (P, acc.ndim) of local maxima >= min_votes, strongest first (ties: lowest index)."""
    mode = ["constant"] * acc.ndim
    if wrap_axis is not None:
        mode[wrap_axis] = "wrap"
    mx = ndimage.maximum_filter(acc, size=size, mode=mode)
    idx = np.argwhere((acc == mx) & (acc >= min_votes) & (acc > 0))
    order = np.lexsort((*idx.T[::-1], -acc[tuple(idx.T)]))
    return idx[order][:max_peaks]


@dataclass
class Line:
    """A line ``x cos t - y sin t = d`` (d in pixels, t in degrees) and its votes."""

    d: float
    theta_deg: float
    votes: float

    def points(self, length: float = 1000.0) -> np.ndarray:
        """Two (x, y) points on the line, ``length`` apart, around the foot of the normal."""
        t = np.radians(self.theta_deg)
        n = np.array([np.cos(t), -np.sin(t)])
        foot, along = self.d * n, np.array([np.sin(t), np.cos(t)])
        return np.array([foot - along * length / 2, foot + along * length / 2])


def hough_lines(image, *, d_res: float = 1.0, theta_res_deg: float = 1.0, threshold: float = 0.2,
                min_votes: float | None = None, max_lines: int = 20, use_orientation: bool = False,
                orientation_window_deg: float = 10.0, weight_by_magnitude: bool = False,
                edges: np.ndarray | None = None, refine: bool = True, min_distance: float = 9.0,
                min_angle_deg: float = 10.0) -> list[Line]:
    """Lines ``x cos t - y sin t = d`` in ``image`` (grey or colour), strongest first.

    d_res, theta_res_deg : accumulator resolution (pixels, degrees). min_votes : default a tenth of the image
    diagonal (in votes, or in summed magnitude share with ``weight_by_magnitude``). ``edges`` : use this
    (H, W) bool edge map instead of the built-in one. ``refine``: each peak is refined by the vote-weighted mean
    of its 3x3 neighbourhood (sub-bin precision). ``min_distance`` (px) and ``min_angle_deg``: a peak must be
    the largest within that window (scikit-image's defaults), so one thick edge gives one line.
    """
    e, gx, gy = edge_map(image, threshold)
    if edges is not None:
        if np.shape(edges) != e.shape:
            raise InputError(f"edges is {np.shape(edges)}, the image {e.shape}")
        e = np.asarray(edges, bool)
    ys, xs = np.nonzero(e)
    H, W = e.shape
    diag = float(np.ceil(np.hypot(H, W)))  # an integer offset keeps d = 0 on a bin centre
    thetas = np.arange(0.0, 180.0, theta_res_deg)
    n_d = int(np.ceil(2 * diag / d_res)) + 1
    acc = np.zeros((n_d, len(thetas)))
    mag = np.hypot(gx, gy)[ys, xs]
    w = mag / mag.max() if weight_by_magnitude and len(mag) and mag.max() > 0 else np.ones(len(xs))
    t = np.radians(thetas)
    if use_orientation:
        # normal direction of the edge from the gradient, as an angle of the form (cos t, -sin t), mod 180
        g_t = np.degrees(np.arctan2(-gy[ys, xs], gx[ys, xs])) % 180.0
        diff = np.abs((thetas[None, :] - g_t[:, None] + 90.0) % 180.0 - 90.0)
        mask = diff <= orientation_window_deg
    for j in range(len(thetas)):
        sel = mask[:, j] if use_orientation else slice(None)
        d = xs[sel] * np.cos(t[j]) - ys[sel] * np.sin(t[j])
        k = np.rint((d + diag) / d_res).astype(int)
        acc[:, j] += np.bincount(k, weights=w[sel], minlength=n_d)[:n_d]
    if min_votes is None:
        min_votes = diag / 10 * (float(np.mean(w)) if weight_by_magnitude and len(w) else 1.0)
    out = []
    win = (2 * int(round(min_distance / d_res)) + 1, 2 * int(round(min_angle_deg / theta_res_deg)) + 1)
    for i, j in _peaks(acc, min_votes, win, max_lines):
        d, th = i * d_res - diag, thetas[j]
        if refine:
            ii = np.clip(np.arange(i - 1, i + 2), 0, n_d - 1)
            jj = np.arange(j - 1, j + 2)
            sub = acc[np.ix_(ii, jj % len(thetas))]
            if sub.sum() > 0:
                d = float((sub.sum(axis=1) @ (ii * d_res - diag)) / sub.sum())
                th = float((sub.sum(axis=0) @ (jj * theta_res_deg)) / sub.sum())
        if th < 0 or th >= 180:  # wrapped past 0/180: the same line with the opposite normal
            th, d = th % 180.0, -d
        out.append(Line(float(d), float(th), float(acc[i, j])))
    return out


@dataclass
class Circle:
    """A circle: centre (x, y) and radius r in pixels, and its score."""

    x: float
    y: float
    r: float
    votes: float


def hough_circles(image, radii, *, threshold: float = 0.2, min_votes: float | None = None, max_circles: int = 50,
                  edges: np.ndarray | None = None, min_separation: float | None = None) -> list[Circle]:
    """Circles of the given ``radii`` (pixels), strongest first. Each edge pixel votes for the two centres along
    its gradient direction at each radius. A candidate's score is the votes within two pixels of its centre
    divided by its circumference, so radii compete fairly; ``min_votes`` is the least score (default 0.3:
    about 30 % of the circle's outline seen as edges). ``min_separation``: least distance between centres
    (default the smallest radius)."""
    e, gx, gy = edge_map(image, threshold)
    if edges is not None:
        e = np.asarray(edges, bool)
    ys, xs = np.nonzero(e)
    mag = np.hypot(gx[ys, xs], gy[ys, xs])
    ok = mag > 0
    ys, xs, ux, uy = ys[ok], xs[ok], gx[ys, xs][ok] / mag[ok], gy[ys, xs][ok] / mag[ok]
    H, W = e.shape
    radii = np.asarray(radii, float)
    acc = np.zeros((len(radii), H, W))
    for k, r in enumerate(radii):
        for sgn in (1, -1):
            cx = np.rint(xs + sgn * r * ux).astype(int)
            cy = np.rint(ys + sgn * r * uy).astype(int)
            inside = (cx >= 0) & (cx < W) & (cy >= 0) & (cy < H)
            np.add.at(acc[k], (cy[inside], cx[inside]), 1.0)
        acc[k] = ndimage.uniform_filter(acc[k], 5) * 25 / (2 * np.pi * r)  # votes within 2 px per unit length
    if min_votes is None:
        min_votes = 0.3
    sep = min_separation if min_separation is not None else max(3.0, radii.min())
    size = (3, 2 * int(sep) + 1, 2 * int(sep) + 1)
    out = []
    for k, y, x in _peaks(acc, min_votes, size, max_circles * 4):
        if all(np.hypot(c.x - x, c.y - y) >= sep for c in out):
            # sub-pixel centre: the vote-weighted mean of the 3x3 neighbourhood
            yy, xx = np.clip([y - 1, y, y + 1], 0, H - 1), np.clip([x - 1, x, x + 1], 0, W - 1)
            sub = acc[k][np.ix_(yy, xx)]
            cyf = float(sub.sum(axis=1) @ yy / sub.sum())
            cxf = float(sub.sum(axis=0) @ xx / sub.sum())
            # radius: the median distance of the edge pixels near the found circle (votes are too coarse)
            dist = np.hypot(xs - cxf, ys - cyf)
            near = np.abs(dist - radii[k]) <= 2.0
            rf = float(np.median(dist[near])) if near.any() else float(radii[k])
            out.append(Circle(cxf, cyf, rf, float(acc[k, y, x])))
        if len(out) == max_circles:
            break
    return out


class GeneralizedHough:
    """The generalised Hough transform (Ballard 1981): an R-table, indexed by the gradient orientation of a
    template's edge pixels, of the offsets from each edge pixel to the template's reference point (its centre).
    Detection lets every scene edge pixel vote, through the R-table entries of its orientation, for where the
    reference point lies; rotations and scales are searched by turning and scaling the table."""

    def __init__(self, template, threshold: float = 0.2, orientation_bins: int = 64):
        e, gx, gy = edge_map(template, threshold)
        ys, xs = np.nonzero(e)
        if len(xs) < 3:
            raise InputError("the template has no edges")
        self.bins = orientation_bins
        self.reference = np.array([(e.shape[1] - 1) / 2, (e.shape[0] - 1) / 2])
        off = self.reference - np.column_stack([xs, ys])
        b = self._bin(np.arctan2(gy[ys, xs], gx[ys, xs]))
        self.table = [off[b == k] for k in range(orientation_bins)]  # R-table: offsets per orientation bin
        self.n_edges = len(xs)

    def _bin(self, ang):
        return (np.floor((np.asarray(ang) % (2 * np.pi)) / (2 * np.pi) * self.bins)).astype(int) % self.bins

    def detect(self, image, rotations_deg=(0.0,), scales=(1.0,), threshold: float = 0.2,
               min_share: float = 0.3, max_found: int = 10) -> list[tuple[float, float, float, float, float]]:
        """Instances in ``image``: (x, y, rotation deg, scale, score), strongest first. The score is the votes
        within one pixel of the reference point per template edge pixel (it can pass 1: a step edge gives a
        pixel on each side); only instances scoring at least ``min_share`` are kept. Rotations turn x toward
        y (clockwise as displayed, y down)."""
        e, gx, gy = edge_map(image, threshold)
        ys, xs = np.nonzero(e)
        ang = np.arctan2(gy[ys, xs], gx[ys, xs])
        H, W = e.shape
        found = []
        for rot in rotations_deg:
            c, s = np.cos(np.radians(rot)), np.sin(np.radians(rot))
            R = np.array([[c, -s], [s, c]])
            for sc in scales:
                acc = np.zeros((H, W))
                # the scene pixel's orientation, turned back by rot, indexes the template's table
                b = self._bin(ang - np.radians(rot))
                for k in range(self.bins):
                    sel = np.flatnonzero(b == k)
                    if len(self.table[k]) == 0 or len(sel) == 0:
                        continue
                    offs = self.table[k] @ R.T * sc
                    cx = np.rint(xs[sel, None] + offs[None, :, 0]).astype(int).ravel()
                    cy = np.rint(ys[sel, None] + offs[None, :, 1]).astype(int).ravel()
                    inside = (cx >= 0) & (cx < W) & (cy >= 0) & (cy < H)
                    np.add.at(acc, (cy[inside], cx[inside]), 1.0)
                acc = ndimage.uniform_filter(acc, 3) * 9  # votes within one pixel of the peak
                for y, x in _peaks(acc, min_share * self.n_edges * sc, (7, 7), max_found):
                    found.append((float(x), float(y), float(rot), float(sc), float(acc[y, x] / (self.n_edges * sc))))
        found.sort(key=lambda f: -f[4])
        kept = []
        for f in found:  # one instance per place: the best rotation and scale
            if all(np.hypot(f[0] - g[0], f[1] - g[1]) > 5 for g in kept):
                kept.append(f)
        return kept[:max_found]


def vote_keypoint_matches(model_kp, scene_kp, reference, *, xy_bin: float = 16.0, rot_bin_deg: float = 30.0,
                          scale_base: float = 2.0, min_votes: int = 3) -> list[tuple[np.ndarray, np.ndarray]]:
    """Hough voting of oriented keypoint matches (Lowe 2004) over translation, scale and rotation.

    model_kp, scene_kp : (M, 4) matched keypoints ``(x, y, scale, angle deg)``, row i matched to row i;
    reference : (2,) the model point whose scene position is voted for. Each match predicts the similarity
    (rotation = scene angle - model angle, scale ratio, and where the reference lands) and votes into bins of
    ``xy_bin`` px, ``rot_bin_deg`` and powers of ``scale_base``, and into the neighbouring bin in each
    dimension as Lowe does (16 votes per match). Returns clusters ``(match indices, [x, y, rot_deg, scale])``
    with at least ``min_votes`` distinct matches, largest first; the pose is the members' median."""
    m, s = np.asarray(model_kp, float), np.asarray(scene_kp, float)
    if m.shape != s.shape or m.ndim != 2 or m.shape[1] != 4:
        raise InputError(f"model_kp and scene_kp must both be (M, 4), got {m.shape} and {s.shape}")
    rot = (s[:, 3] - m[:, 3]) % 360.0
    scale = s[:, 2] / m[:, 2]
    c, sn = np.cos(np.radians(rot)), np.sin(np.radians(rot))
    d = np.asarray(reference, float) - m[:, :2]
    ref = s[:, :2] + scale[:, None] * np.column_stack([c * d[:, 0] - sn * d[:, 1], sn * d[:, 0] + c * d[:, 1]])
    g = np.column_stack([ref / xy_bin, rot / rot_bin_deg, np.log(scale) / np.log(scale_base)])
    base = np.floor(g).astype(int)
    frac = g - base
    votes: dict[tuple, set] = {}
    n_rot = int(round(360.0 / rot_bin_deg))
    for i in range(len(g)):
        for corner in np.ndindex(2, 2, 2, 2):
            # the bin itself and, per dimension, the neighbour on the side the value leans to
            key = tuple(int(base[i, k] + (corner[k] * (1 if frac[i, k] >= 0.5 else -1))) for k in range(4))
            key = (key[0], key[1], key[2] % n_rot, key[3])
            votes.setdefault(key, set()).add(i)
    clusters = sorted(((sorted(v), k) for k, v in votes.items() if len(v) >= min_votes),
                      key=lambda x: (-len(x[0]), x[1]))
    out, seen = [], []
    for members, _ in clusters:
        mset = set(members)
        if any(len(mset & o) >= 0.5 * len(mset) for o in seen):
            continue  # the same cluster, seen from a neighbouring bin
        seen.append(mset)
        idx = np.array(members)
        r = np.degrees(np.angle(np.mean(np.exp(1j * np.radians(rot[idx])))))
        out.append((idx, np.array([*np.median(ref[idx], axis=0), r % 360.0, float(np.median(scale[idx]))])))
    return out
