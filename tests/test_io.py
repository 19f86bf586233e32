"""Readers and writers in pcdet.io: BOP results CSV, point-cloud files, atomic writes, JSON with file names
in its errors."""
import json

import numpy as np
import pytest

from pcdet.errors import InputError
from pcdet.io.atomic import atomic_write_bytes, atomic_write_text
from pcdet.io.bop import (
    camera_pose_from_bop,
    camera_pose_to_bop,
    pose_from_bop,
    pose_to_bop,
    read_results_csv,
    results_row,
    write_results_csv,
)
from pcdet.io.clouds import read_cloud
from pcdet.io.jsonfile import read_json
from pcdet.io.models import load_geometry

from .conftest import random_pose, shared


def test_bop_csv_round_trip(tmp_path, rng):
    """A row written by results_row (R row-major, t in mm) comes back as T_cam_model in metres; the text is
    BOP's: 9 numbers, then 3 in mm."""
    T = random_pose(rng)
    row = results_row(3, 7, 12, 0.5, T, -1)
    assert row[4].split()[1] == f"{T[0, 1]:.9f}" and row[5].split()[2] == f"{T[2, 3] * 1000:.6f}"
    write_results_csv(tmp_path / "r.csv", [row])
    assert (tmp_path / "r.csv").read_text().splitlines()[0] == "scene_id,im_id,obj_id,score,R,t,time"
    (back,) = read_results_csv(tmp_path / "r.csv")
    assert (back["scene_id"], back["im_id"], back["obj_id"], back["score"], back["time"]) == (3, 7, 12, 0.5, -1.0)
    np.testing.assert_allclose(back["T_cam_model"], T, atol=1e-9)


def test_bop_pose_entries_round_trip(rng):
    """Object poses keep R row-major and t in mm; camera poses are stored world-to-camera (BOP's cam_R_w2c)."""
    T = random_pose(rng)
    e = pose_to_bop(T)
    assert e["cam_R_m2c"][1] == T[0, 1] and e["cam_t_m2c"][2] == pytest.approx(T[2, 3] * 1000)
    np.testing.assert_allclose(pose_from_bop(e), T, atol=1e-12)
    c = camera_pose_to_bop(T)
    T_cw = np.linalg.inv(T)
    assert c["cam_t_w2c"][0] == pytest.approx(T_cw[0, 3] * 1000)
    np.testing.assert_allclose(camera_pose_from_bop(c), T, atol=1e-12)


def test_bop_csv_errors_name_the_file_and_line(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("scene_id,im_id,obj_id,score,R,t,time\n1,0,1,0.5,1 0 0 0 1 0 0 0 1,0 0 500,-1\n"
                 "1,0,1,x,1 0 0,0 0 1,-1\n")
    with pytest.raises(InputError, match=r"r\.csv: line 3: malformed row"):
        read_results_csv(p)
    p.write_text("scene_id,im_id,obj_id,score,R,t,time\n1,2,3\n")  # a row cut short
    with pytest.raises(InputError, match=r"r\.csv: line 2: the row ends before column\(s\) score, R, t; expected "
                                         r"scene_id,im_id,obj_id,score,R,t,time"):
        read_results_csv(p)
    p.write_text("scene_id,im_id,score\n")
    with pytest.raises(InputError, match=r"lacks column\(s\) \['R', 'obj_id', 't'\]"):
        read_results_csv(p)
    with pytest.raises(FileNotFoundError, match="nope.csv"):
        read_results_csv(tmp_path / "nope.csv")


def test_clouds_xyz_with_normals_and_nan_rows(tmp_path):
    a = np.array([[0.0, 0, 1, 0, 0, -1], [np.nan, 0, 1, 0, 0, -1], [0.1, 0.2, 1.1, 0, 1, 0]])
    np.savetxt(tmp_path / "c.xyz", a)
    c = read_cloud(tmp_path / "c.xyz")
    np.testing.assert_array_equal(c.points, a[[0, 2], :3])
    np.testing.assert_array_equal(c.normals, a[[0, 2], 3:])
    assert c.shape is None and len(read_cloud(tmp_path / "c.xyz", keep_invalid=True).points) == 3
    np.savetxt(tmp_path / "two.xyz", a[:, :2])
    with pytest.raises(InputError, match="at least 3 columns"):
        read_cloud(tmp_path / "two.xyz")
    (tmp_path / "c.obj").write_text("v 0 0 0\n")
    with pytest.raises(InputError, match="unknown point-cloud format '.obj'"):
        read_cloud(tmp_path / "c.obj")


@pytest.mark.real
def test_organized_pcd_keeps_its_layout():
    """PCL's scene.pcd: 640 x 480, NaN where the Kinect saw nothing; kept as a grid unless invalid points are
    dropped."""
    p = shared("pcl_milk") / "scene.pcd"
    c = read_cloud(p, keep_invalid=True)
    assert c.shape == (480, 640) and len(c.points) == 307200 and c.colors is not None
    finite = read_cloud(p)
    assert finite.shape is None and len(finite.points) == int(np.isfinite(c.points).all(axis=1).sum())


def test_atomic_write_replaces_whole_and_cleans_up(tmp_path):
    p = tmp_path / "sub" / "f.txt"
    atomic_write_text(p, "old")
    atomic_write_text(p, "new")
    assert p.read_text() == "new" and sorted(x.name for x in p.parent.iterdir()) == ["f.txt"]
    with pytest.raises(TypeError):
        atomic_write_bytes(p, object())  # not bytes: the write fails, the old file stays, no temp file
    assert p.read_text() == "new" and sorted(x.name for x in p.parent.iterdir()) == ["f.txt"]


def test_read_json_names_the_file(tmp_path):
    (tmp_path / "a.json").write_text('{"x": 1}')
    assert read_json(tmp_path / "a.json") == {"x": 1}
    (tmp_path / "b.json").write_text("{x: 1")
    with pytest.raises(InputError, match=r"b\.json: file is not valid JSON"):
        read_json(tmp_path / "b.json")
    (tmp_path / "c.json").write_text(json.dumps([1, 2]))
    with pytest.raises(InputError, match=r"c\.json: file must hold a JSON object"):
        read_json(tmp_path / "c.json")
    assert read_json(tmp_path / "c.json", expect_object=False) == [1, 2]
    with pytest.raises(FileNotFoundError, match=r"d\.json"):
        read_json(tmp_path / "d.json")


def test_an_ascii_ply_with_nan_and_inf_rows_reads_its_finite_points(tmp_path):
    """An ASCII PLY as PCL writes an organised cloud (rows of nan, and here inf) with normals and 8-bit colours:
    the finite points read back in file order with their normals and colours (colours within 1e-9 of value / 255).
    open3d's reader stopped at the inf and returned the rest undefined (values of order 1e-310). A token that is
    not a number is refused in one error naming the file."""
    head = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
            "property float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\n"
            "property uchar blue\nend_header\n")
    rows = ["0 0 1 0 0 -1 255 0 0", "nan nan nan nan nan nan 0 0 0", "inf inf inf 0 0 1 0 0 0",
            "0.5 0.25 1.5 0 1 0 0 128 255"]
    (tmp_path / "pcl.ply").write_text(head + "\n".join(rows) + "\n")
    c = read_cloud(tmp_path / "pcl.ply")
    assert np.array_equal(c.points, [[0, 0, 1], [0.5, 0.25, 1.5]])
    assert np.array_equal(c.normals, [[0, 0, -1], [0, 1, 0]])
    assert np.allclose(c.colors, [[1, 0, 0], [0, 128 / 255, 1]], atol=1e-9)
    (tmp_path / "word.ply").write_text(head + "\n".join(rows[:3] + ["0 abc 1 0 0 1 0 0 0"]) + "\n")
    with pytest.raises(InputError, match=r"word\.ply: vertex list holds a value that is not a number"):
        read_cloud(tmp_path / "word.ply")


@pytest.mark.real
def test_every_stanford_range_scan_reads():
    """The Cyberware PLYs (obj_info lines, a range_grid element) that open3d's reader refuses: all 15 read, with
    the vertex count their headers declare and coordinates of a 20 cm dragon in metres."""
    scans = sorted(shared("stanford_scans").glob("*.ply"))
    assert len(scans) == 15
    for p in scans:
        head = p.read_bytes()[:4096].decode("ascii", "replace")
        n = int(head.split("element vertex ")[1].split()[0])
        pts = read_cloud(p).points
        assert len(pts) == n, p.name
        assert 0.1 < np.ptp(pts, axis=0).max() < 0.3, p.name


@pytest.mark.parametrize("suffix, declares", [("ply", "1000 'vertex' elements"), ("pcd", "1000 points")])
def test_a_truncated_cloud_is_refused_not_read_as_garbage(tmp_path, suffix, declares):
    """A PLY or PCD cut short (a copy that did not finish) is refused with the counts its header promises: binary
    and ASCII clouds of 1000 points cut in half. open3d's reader would return the missing points undefined (or,
    for a binary PCD, no points at all). The same clouds whole read back their 1000 points."""
    import open3d as o3d

    pts = np.random.default_rng(3).random((1000, 3)) + [0, 0, 1]
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    for ascii in (False, True):
        whole = tmp_path / f"whole_{ascii}.{suffix}"
        o3d.io.write_point_cloud(str(whole), pc, write_ascii=ascii)
        assert np.allclose(read_cloud(whole).points, pts, atol=1e-5)
        data = whole.read_bytes()
        cut = tmp_path / f"cut_{ascii}.{suffix}"
        cut.write_bytes(data[: len(data) // 2])
        with pytest.raises(InputError, match=rf"cut_{ascii}\.{suffix}: {suffix.upper()} file is truncated: its "
                                             rf"header declares {declares}"):
            read_cloud(cut)


def test_a_truncated_mesh_ply_is_refused(tmp_path):
    """A binary mesh PLY cut within its vertices is refused with its header's counts; cut within its face list
    (past the least a list can take, its count), trimesh's reader refuses it. Either way one error names it."""
    import trimesh

    data = trimesh.creation.icosphere(subdivisions=3).export(file_type="ply")  # binary, with a face list
    cut = tmp_path / "cutmesh.ply"
    cut.write_bytes(data[: len(data) // 4])
    with pytest.raises(InputError, match=r"cutmesh\.ply: PLY file is truncated"):
        load_geometry(cut)
    cut.write_bytes(data[: len(data) - 200])
    with pytest.raises(InputError, match=r"cutmesh\.ply: cannot read model"):
        load_geometry(cut)


def test_a_file_that_is_not_ply_is_named(tmp_path):
    (tmp_path / "x.ply").write_text("this is not a ply\n")
    with pytest.raises(InputError) as e:
        read_cloud(tmp_path / "x.ply")
    assert "x.ply: not a PLY file" in str(e.value)


@pytest.mark.parametrize("layout", ["binary_little_endian", "binary_big_endian", "ascii", "faces_first"])
def test_a_ply_reads_back_the_values_written(tmp_path, rng, layout):
    """A cloud with float normals and uchar colours, written by plyfile as binary (either byte order), as ASCII,
    and with a face element before the vertices (read by plyfile rather than numpy on the header's layout): the
    points and normals come back as written (float32), the colours divided by 255."""
    import plyfile

    from pcdet.io.clouds import read_cloud

    n = 500
    pts, nrm = rng.normal(size=(n, 3)).astype(np.float32), rng.normal(size=(n, 3)).astype(np.float32)
    col = rng.integers(0, 256, size=(n, 3)).astype(np.uint8)
    v = np.empty(n, dtype=[(k, "f4") for k in ("x", "y", "z", "nx", "ny", "nz")] + [(k, "u1") for k in
                                                                                    ("red", "green", "blue")])
    for i, k in enumerate("xyz"):
        v[k], v["n" + k] = pts[:, i], nrm[:, i]
    for i, k in enumerate(("red", "green", "blue")):
        v[k] = col[:, i]
    vertex = plyfile.PlyElement.describe(v, "vertex")
    faces = np.empty(0, dtype=[("vertex_indices", "i4", (3,))])
    face = plyfile.PlyElement.describe(faces, "face")
    elements = [face, vertex] if layout == "faces_first" else [vertex]
    big = layout == "binary_big_endian"
    p = tmp_path / "c.ply"
    plyfile.PlyData(elements, text=layout == "ascii", byte_order=">" if big else "<").write(str(p))
    cd = read_cloud(p)
    np.testing.assert_array_equal(cd.points, pts.astype(np.float64))
    np.testing.assert_array_equal(cd.normals, nrm.astype(np.float64))
    np.testing.assert_allclose(cd.colors, col / 255.0)
