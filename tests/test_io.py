"""Readers and writers in pcdet.io: BOP results CSV, point-cloud files, atomic writes, JSON with file names
in its errors."""
import json

import numpy as np
import pytest

from pcdet.errors import InputError
from pcdet.io.atomic import atomic_write_bytes, atomic_write_text
from pcdet.io.clouds import read_cloud
from pcdet.io.jsonfile import read_json
from pcdet.io.results import read_bop_csv, write_bop_csv

from .conftest import random_pose, shared


def test_bop_csv_round_trip(tmp_path, rng):
    """Rows written with R row-major and t in mm come back as T_cam_model in metres."""
    T = random_pose(rng)
    R = " ".join(f"{v:.9f}" for v in T[:3, :3].reshape(-1))
    t = " ".join(f"{v * 1000:.6f}" for v in T[:3, 3])
    write_bop_csv(tmp_path / "r.csv", [["3", "7", "12", "0.5", R, t, "-1"]])
    assert (tmp_path / "r.csv").read_text().splitlines()[0] == "scene_id,im_id,obj_id,score,R,t,time"
    (row,) = read_bop_csv(tmp_path / "r.csv")
    assert (row["scene_id"], row["im_id"], row["obj_id"], row["score"], row["time"]) == (3, 7, 12, 0.5, -1.0)
    np.testing.assert_allclose(row["T_cam_model"], T, atol=1e-9)


def test_bop_csv_errors_name_the_file_and_line(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("scene_id,im_id,obj_id,score,R,t,time\n1,0,1,0.5,1 0 0 0 1 0 0 0 1,0 0 500,-1\n1,0,1,x,1 0 0,0 0 1,-1\n")
    with pytest.raises(InputError, match=r"r\.csv: line 3: malformed row"):
        read_bop_csv(p)
    p.write_text("scene_id,im_id,score\n")
    with pytest.raises(InputError, match=r"lacks column\(s\) \['R', 'obj_id', 't'\]"):
        read_bop_csv(p)
    with pytest.raises(FileNotFoundError, match="nope.csv"):
        read_bop_csv(tmp_path / "nope.csv")


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
    with pytest.raises(InputError, match=r"b\.json: not valid JSON"):
        read_json(tmp_path / "b.json")
    (tmp_path / "c.json").write_text(json.dumps([1, 2]))
    with pytest.raises(InputError, match=r"c\.json: expected a JSON object"):
        read_json(tmp_path / "c.json")
    assert read_json(tmp_path / "c.json", expect_object=False) == [1, 2]
    with pytest.raises(FileNotFoundError, match=r"d\.json"):
        read_json(tmp_path / "d.json")
