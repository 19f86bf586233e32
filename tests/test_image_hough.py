"""Hough transforms on drawn shapes with known answers, and on real photographs shipped by scikit-image."""
import numpy as np
import pytest

from pcdet.image.hough import (
    GeneralizedHough,
    edge_map,
    hough_circles,
    hough_lines,
    vote_keypoint_matches,
)


def _polygon(shape, lines):
    """Filled convex region: pixel centres with x cos t - y sin t < d for every (d, t); its sides lie on the
    given lines."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    inside = np.ones(shape, bool)
    for d, t in lines:
        tr = np.radians(t)
        inside &= xx * np.cos(tr) - yy * np.sin(tr) < d
    return inside.astype(float)


def _angle_diff(a, b):
    return abs((a - b + 90.0) % 180.0 - 90.0)


def _canon(d, t):
    """(d, t) with t in [0, 180): (d, t) and (-d, t - 180) are the same line."""
    t = t % 360.0
    return (-d, t - 180.0) if t >= 180.0 else (d, t)


def _line_error(ln, d, t):
    """(|d error| px, angle error deg) between a found line and (d, t), across the 0/180 wrap."""
    d, t = _canon(d, t)
    errs = []
    for dd, tt in ((ln.d, ln.theta_deg), (-ln.d, ln.theta_deg + 180.0), (-ln.d, ln.theta_deg - 180.0)):
        errs.append((abs(dd - d), abs(tt - t)))
    return min(errs)


# a quadrilateral: pixel centres with x cos t - y sin t < d for each side (d px, t deg)
QUAD = [(250.0, 10.0), (-40.0, 190.0), (-30.0, 95.0), (200.0, 268.0)]


@pytest.mark.parametrize("options", [{}, {"use_orientation": True}, {"weight_by_magnitude": True},
                                     {"use_orientation": True, "weight_by_magnitude": True}])
def test_every_drawn_line_within_1px_and_1deg(options):
    """The region's sides lie between the last pixel centre inside and the first outside; every side is found
    within 1 px and 1 deg, with each voting option."""
    img = _polygon((240, 320), QUAD)
    assert 0.3 < img.mean() < 0.9
    found = hough_lines(img, max_lines=8, **options)
    for d, t in QUAD:
        err = min(_line_error(ln, d, t) for ln in found)
        assert err[0] < 1.0 and err[1] < 1.0, (d, t, err, [(ln.d, ln.theta_deg) for ln in found])


def test_drawn_circles_within_1px():
    yy, xx = np.mgrid[0:220, 0:260]
    truth = [(60.3, 70.7, 25.0), (170.0, 120.0, 40.0), (80.0, 170.0, 18.0)]
    img = np.zeros((220, 260))
    for cx, cy, r in truth:
        img[(xx - cx) ** 2 + (yy - cy) ** 2 < r ** 2] = 1
    found = hough_circles(img, np.arange(14, 46))
    assert len(found) >= 3
    for cx, cy, r in truth:
        c = min(found, key=lambda c: np.hypot(c.x - cx, c.y - cy))
        assert np.hypot(c.x - cx, c.y - cy) < 1.0 and abs(c.r - r) < 1.0, (cx, cy, r, c)


def test_generalised_hough_finds_a_shape_turned_and_moved():
    """An arrow-like template; the scene holds it turned by 30 deg at (150, 110) and a disc as clutter."""
    from scipy import ndimage

    tpl = np.zeros((61, 61))
    tpl[20:41, 10:45] = 1
    tpl[10:51, 40:52] = 1  # a T: no rotational symmetry
    scene = np.zeros((240, 300))
    turned = ndimage.rotate(tpl, 30.0, reshape=True, order=0)
    h, w = turned.shape
    y0, x0 = 110 - (h - 1) // 2, 150 - (w - 1) // 2
    scene[y0:y0 + h, x0:x0 + w] = np.maximum(scene[y0:y0 + h, x0:x0 + w], turned)
    yy, xx = np.mgrid[0:240, 0:300]
    scene[(xx - 50) ** 2 + (yy - 60) ** 2 < 20 ** 2] = 1
    ght = GeneralizedHough(tpl)
    found = ght.detect(scene, rotations_deg=range(0, 360, 15))
    x, y, rot, scale, score = found[0]
    # ndimage.rotate turns counter-clockwise as displayed (y down): -30 deg in x-right, y-down coordinates
    assert np.hypot(x - 150, y - 110) <= 2.0 and rot == 330.0 and score > 0.5, found[:3]


def test_keypoint_votes_group_the_consistent_matches(rng):
    """30 matches of oriented keypoints under one similarity (rotation 40 deg, scale 1.5, a shift) and 30
    random ones: the largest cluster holds the 30 and gives the pose."""
    n = 30
    m = np.column_stack([rng.uniform(0, 200, (n, 2)), rng.uniform(1, 4, n), rng.uniform(0, 360, n)])
    c, s = np.cos(np.radians(40)), np.sin(np.radians(40))
    xy = 1.5 * m[:, :2] @ np.array([[c, -s], [s, c]]).T + [300, 50]
    sc = np.column_stack([xy, m[:, 2] * 1.5, (m[:, 3] + 40) % 360])
    junk_m = np.column_stack([rng.uniform(0, 200, (n, 2)), rng.uniform(1, 4, n), rng.uniform(0, 360, n)])
    junk_s = np.column_stack([rng.uniform(0, 500, (n, 2)), rng.uniform(1, 4, n), rng.uniform(0, 360, n)])
    clusters = vote_keypoint_matches(np.vstack([m, junk_m]), np.vstack([sc, junk_s]), reference=[100, 100])
    idx, pose = clusters[0]
    assert set(range(n)) <= set(idx.tolist()) and len(idx) <= n + 2
    ref = 1.5 * np.array([[c, -s], [s, c]]) @ [100, 100] + [300, 50]
    assert np.allclose(pose[:2], ref, atol=1e-6) and pose[2] == pytest.approx(40) and pose[3] == pytest.approx(1.5)


def test_real_photographs_agree_with_scikit_image():
    """scikit-image's own photographs. Coins: all 24 coins, each paired one to one with a circle that
    scikit-image's hough_circle / hough_circle_peaks find on its Canny edges (centre within 4.5 px, radius
    within 2.5 px; measured: largest 4.0 px and 2.3 px). Cameraman: the 3 strongest lines on pcdet's edge map
    agree with scikit-image's hough_line on that same edge map within 1 px and 1 deg."""
    pytest.importorskip("skimage")
    from scipy.optimize import linear_sum_assignment
    from skimage import data, feature, transform

    coins = data.coins()
    circles = hough_circles(coins.astype(float), np.arange(18, 34), threshold=0.25, max_circles=30)
    radii = np.arange(18, 34)
    acc = transform.hough_circle(feature.canny(coins, sigma=3, low_threshold=10, high_threshold=50), radii)
    _, cx, cy, cr = transform.hough_circle_peaks(acc, radii, total_num_peaks=24, min_xdistance=20,
                                                 min_ydistance=20)
    assert len(circles) == 24 and len(cx) == 24
    ours = np.array([(c.x, c.y) for c in circles])
    dist = np.hypot(ours[:, None, 0] - cx[None], ours[:, None, 1] - cy[None])
    rows, cols = linear_sum_assignment(dist)
    assert dist[rows, cols].max() <= 4.5, dist[rows, cols]
    assert max(abs(circles[i].r - cr[j]) for i, j in zip(rows, cols)) <= 2.5

    cam = data.camera().astype(float)
    e, _, _ = edge_map(cam, 0.25)
    ours = hough_lines(cam, edges=e, max_lines=3, refine=False)
    # scikit-image: x cos(a) + y sin(a) = r, so our (d, t) = (r, -a)
    h, a, r = transform.hough_line(e, theta=np.radians(np.arange(-90.0, 90.0, 1.0)))
    _, sa, sr = transform.hough_line_peaks(h, a, r, num_peaks=3)
    theirs = [(float(rr), float(-np.degrees(aa))) for aa, rr in zip(sa, sr)]
    assert len(ours) == 3
    for ln in ours:
        err = min(_line_error(ln, d, t) for d, t in theirs)
        assert err[0] <= 1.0 and err[1] <= 1.0, ((ln.d, ln.theta_deg), theirs)
