"""Feature points from a drawn polyhedron (a pyramid seen from above and aside, as in Liu and Wang's Fig. 4.1):
edges, Hough lines, intersections on edges."""
import numpy as np

from pcdet.image.features import feature_points


def _draw_segment(img, p, q):
    n = int(np.ceil(np.hypot(*(np.subtract(q, p))))) * 3 + 1
    xs = np.linspace(p[0], q[0], n)
    ys = np.linspace(p[1], q[1], n)
    img[np.rint(ys).astype(int), np.rint(xs).astype(int)] = True


def test_pyramid_vertices_are_found_from_a_line_drawing():
    """Apex (160, 40), base corners (60, 190), (200, 215), (270, 160); all six edges drawn, the hidden one too.
    Every vertex is found within 1.5 px, and so is the one place where two drawn edges cross (the hidden back
    edge behind the front one): in a wireframe that is an intersection on edges too. Crossings of line
    extensions that lie on no drawn edge are rejected: 5 points in all."""
    apex, base = (160, 40), [(60, 190), (200, 215), (270, 160)]
    img = np.zeros((240, 320), bool)
    for b in base:
        _draw_segment(img, apex, b)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        _draw_segment(img, base[a], base[b])
    pts, lines = feature_points(img, max_lines=6, min_votes=40)
    assert len(lines) == 6
    # where the front edge apex-(200, 215) crosses the back edge (270, 160)-(60, 190)
    A = np.array([[200 - 160, -(60 - 270)], [215 - 40, -(190 - 160)]], float)
    s, _ = np.linalg.solve(A, [270 - 160, 160 - 40])
    crossing = (160 + s * 40, 40 + s * 175)
    for v in [apex, *base, crossing]:
        assert np.min(np.linalg.norm(pts - v, axis=1)) < 1.5, (v, pts)
    assert len(pts) == 5, pts


def test_filled_quadrilateral_corners_from_a_grey_image():
    """A filled quadrilateral (step edges, so Sobel edges): its four corners."""
    corners = np.array([(50.0, 40.0), (260.0, 60.0), (230.0, 200.0), (70.0, 180.0)])
    yy, xx = np.mgrid[0:240, 0:320]
    inside = np.ones((240, 320), bool)
    for a, b in zip(corners, np.roll(corners, -1, axis=0)):
        inside &= (b[0] - a[0]) * (yy - a[1]) - (b[1] - a[1]) * (xx - a[0]) >= 0
    pts, _ = feature_points(inside.astype(float) * 200.0, max_lines=4)
    assert len(pts) == 4
    for c in corners:
        assert np.min(np.linalg.norm(pts - c, axis=1)) < 1.5, (c, pts)
