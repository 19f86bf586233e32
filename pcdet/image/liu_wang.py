"""The worked examples of Liu and Wang, "Recognition of 3D Objects from 2D Images - Some Issues" (the seed
document ../shared/seeds/001_*.txt): feature points of the three model views, the unknown images' fitting
points, and the coefficients as printed. ``None`` marks a number that is garbled in the extracted text; the
sign of one is lost ("±0.26")."""
from __future__ import annotations

PYRAMID = [[(0.10, 1.40), (-2.10, -1.20), (0.80, -1.00), (1.90, -1.70)],
           [(-0.10, 1.30), (-2.10, -1.30), (0.50, -0.50), (2.20, -1.50)],
           [(-0.10, 1.20), (-2.00, -1.40), (0.20, -0.10), (2.30, -1.10)]]
CLOSET_MAIN = [[(-1.90, 0.40), (1.00, -0.20), (1.70, -1.10), (0.70, -2.10)],
               [(-2.00, 0.60), (0.70, -0.50), (1.70, -1.20), (0.30, -2.20)],
               [(-2.00, 0.70), (0.40, -0.70), (1.70, -1.30), (0.00, -2.40)]]
CLOSET_DOOR = [[(-1.90, 0.40), (1.00, 0.30), (2.00, 1.20), (-0.80, 1.30)],
               [(-2.00, 0.60), (0.70, 0.60), (2.10, 1.40), (-0.40, 1.40)],
               [(-2.00, 0.70), (0.40, 0.80), (2.20, 1.70), (-0.10, 1.60)]]

# (example, model views, the unknown image's 4 fitting points, printed x coefficients, printed y coefficients)
EXAMPLES = [
    ("pyramid, same (Fig. 4.1 iv)", PYRAMID, [(-0.20, 1.2), (-2.0, -1.5), (0.0, 0.0), (2.3, -0.9)],
     [-0.23, None, None, -0.06], [0.46, -1.32, None, -0.01]),
    ("pyramid, other (Fig. 4.1 v)", PYRAMID, [(-0.3, 2.3), (-2.0, -1.5), (0.0, 0.0), (2.3, -0.9)],
     [-0.68, None, 0.68, None], [1.87, -3.32, 2.91, None]),
    ("closet main part (Fig. 4.3 iv)", CLOSET_MAIN, [(-2.0, 0.8), (0.3, -0.8), (1.7, -1.3), (-0.2, -2.4)],
     [-1.12, 1.78, 0.31, 0.05], [-0.32, 0.09, 1.21, 0.03]),
    ("closet door (Fig. 4.3 iv)", CLOSET_DOOR, [(-2.0, 0.8), (0.1, 1.2), (2.2, 2.1), (0.0, 1.7)],
     [0.62, -2.00, 2.38, -0.07], [None, 0.67, 1.00, 1.60]),
    ("other closet's door (Fig. 4.3 v)", CLOSET_DOOR, [(-2.0, 0.8), (-1.0, 1.0), (1.1, 1.9), (0.0, 1.7)],
     ["±0.26", -1.68, 2.62, -0.61], [0.50, -0.92, 0.67, 0.40]),
]
