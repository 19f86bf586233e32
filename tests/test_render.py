"""CPU depth rendering, which verification, evaluation (VSD) and synth all trust: checked against geometry
worked out by hand."""
import numpy as np
import pytest
import trimesh

from pcdet.camera import Camera
from pcdet.render import mesh_depth_at, render_meshes, render_points

CAM = Camera(500.0, 500.0, 319.5, 239.5, 640, 480)


def _at(z):
    T = np.eye(4)
    T[2, 3] = z
    return T


def test_a_cube_face_on_renders_its_front_face_at_the_right_size():
    """A 10 cm cube centred 1 m in front: its front face is at 0.95 m, and it spans f * 0.1 / 0.95 = 52.6 px
    across; every rendered pixel back-projects onto the face plane; normals face the camera; ids say which
    mesh was hit."""
    box = trimesh.creation.box((0.1, 0.1, 0.1))
    r = render_meshes(CAM, [(box.vertices, box.faces, _at(1.0))])
    hit = r.depth > 0
    np.testing.assert_allclose(r.depth[hit], 0.95, atol=1e-6)
    cols = np.flatnonzero(hit.any(axis=0))
    assert len(cols) == pytest.approx(500 * 0.1 / 0.95, abs=1.0)
    np.testing.assert_allclose(r.normals[hit], [[0, 0, -1]] * int(hit.sum()), atol=1e-6)
    assert set(np.unique(r.ids[hit])) == {0} and (r.ids[~hit] == -1).all()
    pts, _ = CAM.backproject(r.depth)
    assert np.abs(pts[:, :2]).max() <= 0.05 + 1e-6  # inside the face's square


def test_nearer_mesh_hides_the_farther_one_and_partial_pixels():
    """Two meshes on one ray: the nearer one wins; casting only some pixels renders those alone, equal to
    mesh_depth_at on the same pixels."""
    near = trimesh.creation.box((0.05, 0.05, 0.05))
    far = trimesh.creation.box((0.4, 0.4, 0.02))
    r = render_meshes(CAM, [(far.vertices, far.faces, _at(1.5)), (near.vertices, near.faces, _at(1.0))])
    centre = 240 * 640 + 320
    assert r.ids.reshape(-1)[centre] == 1 and r.depth.reshape(-1)[centre] == pytest.approx(0.975, abs=1e-6)
    pix = np.arange(200 * 640, 280 * 640, 7)
    part = render_meshes(CAM, [(near.vertices, near.faces, _at(1.0))], pix)
    alone = mesh_depth_at(CAM, near.vertices, near.faces, _at(1.0), pix)
    np.testing.assert_array_equal(part.depth.reshape(-1)[pix], alone)
    others = np.setdiff1d(np.arange(640 * 480), pix)
    assert (part.depth.reshape(-1)[others] == 0).all()


def test_point_splatting_fills_a_sampled_plane_without_holes():
    """A plane sampled every 4 mm at 0.8 m (2.5 px apart) splats into a hole-free patch at its depth, whose outline
    is that of the outermost samples' pixels: the splats do not draw it wider (a pose of the right size would see
    through there)."""
    xs, ys = np.meshgrid(np.arange(-0.05, 0.05, 0.004), np.arange(-0.05, 0.05, 0.004))
    pts = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.8)], axis=1)
    d = render_points(CAM, pts, 0.004)
    uv = np.rint(CAM.project(pts)).astype(int)
    u0, v0 = uv.min(axis=0)
    u1, v1 = uv.max(axis=0)
    patch = d[v0:v1 + 1, u0:u1 + 1]
    assert (patch > 0).all() and np.allclose(patch, 0.8)
    assert (d > 0).sum() == patch.size  # no splat margin beyond the outermost samples
    assert render_points(CAM, pts - [0, 0, 1.0], 0.004).max() == 0  # behind the camera: nothing
