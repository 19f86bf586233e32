"""Colour at keypoints: chromaticity, image sampling around projected points, colours from a mesh's vertices."""
import numpy as np
import trimesh

from pcdet.camera import Camera
from pcdet.colour import DARK, chromaticity, image_colours, surface_colours
from pcdet.model import build_model
from pcdet.config import PipelineConfig


def test_chromaticity_ignores_brightness_and_marks_dark_colours_unknown():
    c = chromaticity(np.array([[0.5, 0.5, 0.5], [0.9, 0.9, 0.9], [0.6, 0.3, 0.3], [0.3, 0.15, 0.15],
                               [DARK / 2] * 3]))
    assert np.allclose(c[0], [1, 1]) and np.allclose(c[1], [1, 1])  # greys of any brightness are (1, 1)
    assert np.allclose(c[2], [1.5, 0.75]) and np.allclose(c[2], c[3])  # a red, lit or shaded
    assert np.isnan(c[4]).all()


def test_image_colours_average_the_window_around_each_projection():
    cam = Camera(fx=500, fy=500, cx=32, cy=24, width=64, height=48)
    rgb = np.zeros((48, 64, 3), np.uint8)
    rgb[:, :32] = (255, 0, 0)
    rgb[:, 32:] = (0, 0, 255)
    pts = np.array([[-0.02, 0.0, 1.0], [0.02, 0.0, 1.0], [0.0, 0.0, -1.0]])  # left (red), right (blue), behind
    col = image_colours(pts, cam, rgb, window=2)
    assert np.allclose(col[0], [1, 0, 0]) and np.allclose(col[1], [0, 0, 1])
    assert np.isnan(col[2]).all()


def test_surface_colours_take_the_nearest_vertices():
    verts = np.array([[0, 0, 0], [1, 0, 0]], float)
    cols = np.array([[1, 0, 0], [0, 1, 0]], float)
    out = surface_colours(np.array([[0.1, 0, 0], [0.9, 0, 0]]), verts, cols, k=1)
    assert np.allclose(out, cols)


def test_a_mesh_with_vertex_colours_gives_coloured_keypoints_and_one_without_none(tmp_path):
    box = trimesh.creation.box((0.1, 0.06, 0.04))
    plain = tmp_path / "plain.ply"
    box.export(plain)
    box = box.subdivide().subdivide()  # vertices across each face, so that colours vary along it
    coloured = box.copy()
    right = box.vertices[:, 0] > 0
    coloured.visual.vertex_colors = np.where(right[:, None], [200, 40, 40, 255], [40, 200, 40, 255]).astype(np.uint8)
    painted = box.copy()
    painted.visual.vertex_colors = np.tile([0, 0, 255, 255], (len(box.vertices), 1)).astype(np.uint8)
    for name, mesh in (("red_green.ply", coloured), ("painted.ply", painted)):
        mesh.export(tmp_path / name)
    cfg = PipelineConfig()
    m, m_plain, m_paint = (build_model(tmp_path / n, cfg) for n in ("red_green.ply", "plain.ply", "painted.ply"))
    assert m_plain.kp_colors is None
    assert m_paint.kp_colors is None  # one colour on every vertex is a tool's paint, not the object's look
    assert m.kp_colors.shape == (len(m.kp_points), 3)
    far_right, far_left = m.kp_points[:, 0] > 0.03, m.kp_points[:, 0] < -0.03
    assert far_right.any() and far_left.any()
    assert (m.kp_colors[far_right, 0] > m.kp_colors[far_right, 1]).all()
    assert (m.kp_colors[far_left, 1] > m.kp_colors[far_left, 0]).all()
