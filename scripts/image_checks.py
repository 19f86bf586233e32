"""The figures issue 5 asks for, in one run: the Liu and Wang coefficients (paper vs pcdet), homography and
affine recovery from noisy matches with 50 % outliers (20 trials), and Hough results on scikit-image's coins and
cameraman photographs (the latter beside scikit-image's own hough_line).

Run:  python scripts/image_checks.py
"""
from __future__ import annotations

import numpy as np

from pcdet.image import LinearCombination, ransac_affine, ransac_homography
from pcdet.image.hough import edge_map, hough_circles, hough_lines
from pcdet.image.liu_wang import EXAMPLES
from pcdet.image.transforms import apply


def _fmt(v):
    return "?" if v is None else (v if isinstance(v, str) else f"{v:.2f}")


def lcm_table():
    print("| example | coefficient | paper | pcdet |")
    print("|---|---|---|---|")
    for name, views, pts, px, py in EXAMPLES:
        lc = LinearCombination().fit(views, pts, allow_degenerate=True)
        for axis, paper, got, rank in (("x", px, lc.coef_x, lc.rank_x), ("y", py, lc.coef_y, lc.rank_y)):
            note = "" if rank == 4 else f" (singular: rank {rank})"
            print(f"| {name} | {axis}: alpha beta gamma delta | {' '.join(_fmt(v) for v in paper)} | "
                  f"{' '.join(f'{v:.2f}' for v in got)}{note} |")


def robust_fits():
    corners = np.array([[0, 0], [640, 0], [640, 480], [0, 480]], float)
    H = np.array([[0.9, 0.12, 30.0], [-0.08, 1.05, 12.0], [2e-4, -1e-4, 1.0]])
    A = np.array([[0.95, -0.2, 40.0], [0.15, 1.1, -25.0], [0.0, 0.0, 1.0]])
    print("\n200 matches, 0.5 px noise, 50 % outliers, 20 trials: largest corner error of a 640x480 image")
    for name, T, fit in (("homography", H, ransac_homography), ("affine", A, ransac_affine)):
        errs = []
        for seed in range(20):
            rng = np.random.default_rng(seed)
            src = rng.uniform([0, 0], [640, 480], (200, 2))
            dst = apply(T, src) + rng.normal(0, 0.5, (200, 2))
            bad = rng.random(200) < 0.5
            dst[bad] = rng.uniform([0, 0], [640, 480], (bad.sum(), 2))
            r = fit(src, dst, threshold=2.0, seed=seed)
            errs.append(np.linalg.norm(apply(r.H, corners) - apply(T, corners), axis=1).max())
        print(f"  {name}: median {np.median(errs):.2f} px, worst {max(errs):.2f} px")


def photographs():
    try:
        from skimage import data, transform
    except ImportError:
        print("\nscikit-image is not installed: no photographs")
        return
    circles = hough_circles(data.coins().astype(float), np.arange(18, 34), threshold=0.25, max_circles=30)
    print(f"\ncoins.png (24 coins): {len(circles)} circles, radii {min(c.r for c in circles):.1f}-"
          f"{max(c.r for c in circles):.1f} px")
    cam = data.camera().astype(float)
    e, _, _ = edge_map(cam, 0.25)
    ours = hough_lines(cam, edges=e, max_lines=3, refine=False)
    h, a, r = transform.hough_line(e, theta=np.radians(np.arange(-90.0, 90.0, 1.0)))
    _, sa, sr = transform.hough_line_peaks(h, a, r, num_peaks=3)
    print("camera.png, 3 strongest lines (d px, t deg): pcdet", [(round(ln.d, 1), round(ln.theta_deg, 1))
                                                                 for ln in ours],
          "scikit-image", [(round(float(rr), 1), round(float(-np.degrees(aa)) % 180, 1)) for aa, rr in zip(sa, sr)])


if __name__ == "__main__":
    lcm_table()
    robust_fits()
    photographs()
