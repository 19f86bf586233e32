"""Scene preprocessing on a rendered table with two boxes and a far wall: range crop, plane removal,
clusters, normals toward the camera."""
import numpy as np
import pytest
import trimesh

from pcdet.camera import Camera
from pcdet.config import PreprocessConfig
from pcdet.errors import InputError
from pcdet.frame import Frame
from pcdet.preprocess import preprocess
from pcdet.render import render_meshes

CAM = Camera(525.0, 525.0, 319.5, 239.5, 640, 480)


def _pose(R=np.eye(3), t=(0, 0, 0)):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


@pytest.fixture(scope="module")
def frame():
    """Camera 0.8 m above a table, looking down at 45 deg; two 6 cm boxes 20 cm apart on it, a tiny 8 mm cube,
    and a wall 3.5 m away."""
    from scipy.spatial.transform import Rotation

    R = Rotation.from_euler("x", -135, degrees=True).as_matrix()  # camera z points down and forward
    T_cam_world = np.linalg.inv(_pose(R, (0, -0.8, 0.8)))
    table = trimesh.creation.box((1.5, 1.5, 0.02))
    box = trimesh.creation.box((0.06, 0.06, 0.06))
    tiny = trimesh.creation.box((0.008, 0.008, 0.008))
    wall = trimesh.creation.box((20, 0.1, 20))
    meshes = [(table.vertices, table.faces, T_cam_world @ _pose(t=(0, 0, -0.01))),
              (box.vertices, box.faces, T_cam_world @ _pose(t=(-0.1, 0, 0.03))),
              (box.vertices, box.faces, T_cam_world @ _pose(t=(0.1, 0, 0.03))),
              (tiny.vertices, tiny.faces, T_cam_world @ _pose(t=(0, 0.2, 0.004))),
              (wall.vertices, wall.faces, T_cam_world @ _pose(t=(0, 3.2, 0)))]
    r = render_meshes(CAM, meshes)
    return Frame(r.depth, CAM), T_cam_world


def test_plane_clusters_range_and_normals(frame):
    f, T_cam_world = frame
    s = preprocess(f, PreprocessConfig(), seed=0)
    # the table's plane is found: its normal is the world's z axis seen from the camera, facing the camera
    up = T_cam_world[:3, :3] @ [0, 0, 1]
    assert s.plane is not None and abs(s.plane.normal @ up) > 0.999 and s.plane.offset > 0
    world = (s.points - T_cam_world[:3, 3]) @ T_cam_world[:3, :3]
    # nothing of the table top or the wall (beyond max_depth 2.5 m) is left; the boxes' points are
    assert world[:, 2].min() > 0.008 - 1e-6 and s.points[:, 2].max() < 2.5
    on_box = [np.all(np.abs(world - [x, 0, 0.03]) <= 0.031, axis=1) for x in (-0.1, 0.1)]
    assert on_box[0].sum() > 100 and on_box[1].sum() > 100 and (on_box[0] | on_box[1]).all()
    # two clusters, one per box; the 8 mm cube is below min_cluster_points and dropped
    assert sorted(np.unique(s.labels)) == [0, 1]
    assert all(len(np.unique(s.labels[b])) == 1 for b in on_box)
    assert s.labels[on_box[0]][0] != s.labels[on_box[1]][0]
    # normals face the camera and are unit length
    assert (np.einsum("ij,ij->i", s.normals, -s.points) > 0).all()
    np.testing.assert_allclose(np.linalg.norm(s.normals, axis=1), 1.0, atol=1e-6)
    assert s.n_input == int((f.depth > 0).sum())


def test_without_plane_removal_the_table_stays(frame):
    f, _ = frame
    s = preprocess(f, PreprocessConfig(remove_plane=False), seed=0)
    assert s.plane is None and len(s.points) > 5 * len(preprocess(f, PreprocessConfig(), seed=0).points)


def test_same_seed_same_cloud(frame):
    f, _ = frame
    a, b = preprocess(f, PreprocessConfig(), seed=3), preprocess(f, PreprocessConfig(), seed=3)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.labels, b.labels)


def test_depth_outside_the_range_is_a_clear_error(frame):
    f, _ = frame
    with pytest.raises(InputError, match="no point between min_depth 0.1 m and max_depth 0.2 m"):
        preprocess(f, PreprocessConfig(max_depth=0.2), seed=0)
