"""Camera files in every accepted layout, bad files, and back-projection."""
import json

import numpy as np
import pytest

from pcdet.camera import Camera
from pcdet.errors import InputError

from .conftest import shared


def test_pcdet_layout_and_roundtrip(tmp_path):
    p = tmp_path / "cam.json"
    p.write_text(json.dumps({"fx": 500, "fy": 510, "cx": 320, "cy": 240, "width": 640, "height": 480}))
    cam = Camera.from_json(p)
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (500, 510, 320, 240, 640, 480)
    assert cam.depth_scale == 1.0 and cam.metres_per_unit == 0.001  # default: 1 mm per raw unit


def test_bop_camera_json_depth_scale_in_mm(tmp_path):
    p = tmp_path / "camera.json"
    p.write_text(json.dumps({"fx": 572.4, "fy": 573.6, "cx": 325.3, "cy": 242.0, "width": 640, "height": 480,
                             "depth_scale": 0.1}))
    assert Camera.from_json(p).depth_scale == pytest.approx(0.1)  # 0.1 mm per unit


@pytest.mark.real
def test_bop_scene_camera_and_open3d_layouts():
    cam = Camera.from_json(shared("ycbv_frame") / "test/000001/scene_camera.json", width=640, height=480)
    assert cam.fx == pytest.approx(1066.778) and cam.depth_scale == pytest.approx(0.1)
    o3d_cam = Camera.from_json(shared("open3d_rgbd") / "camera_primesense.json")
    assert (o3d_cam.fx, o3d_cam.cx, o3d_cam.cy) == (525.0, 319.5, 239.5)  # column-major matrix read right


@pytest.mark.parametrize("content, words", [
    ("{not json", "not valid JSON"),
    ('{"fx": 500, "fy": 500}', "lacks cx, cy"),
    ('{"fx": "a", "fy": 500, "cx": 1, "cy": 1, "width": 640, "height": 480}', "malformed field"),
    ('{"fx": -1, "fy": 500, "cx": 1, "cy": 1, "width": 640, "height": 480}', "fx must be a positive"),
    ('{"focal": 3}', "none of the known layouts"),
    ("[1, 2]", "JSON object"),
])
def test_bad_camera_files_name_the_file(tmp_path, content, words):
    p = tmp_path / "bad_cam.json"
    p.write_text(content)
    with pytest.raises(InputError) as e:
        Camera.from_json(p)
    assert "bad_cam.json" in str(e.value) and words in str(e.value)


def test_missing_camera_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.json"):
        Camera.from_json(tmp_path / "nope.json")


def test_backproject_project_roundtrip(rng):
    cam = Camera(500.0, 505.0, 319.5, 239.5, 640, 480)
    depth = rng.uniform(0.5, 2.0, (480, 640)).astype(np.float32)
    depth[::7, ::5] = 0  # invalid pixels are skipped
    pts, pix = cam.backproject(depth)
    assert len(pts) == (depth > 0).sum()
    uv = cam.project(pts)
    v, u = np.divmod(pix, 640)
    np.testing.assert_allclose(uv[:, 0], u, atol=1e-6)
    np.testing.assert_allclose(uv[:, 1], v, atol=1e-6)
    np.testing.assert_allclose(pts[:, 2], depth.reshape(-1)[pix], rtol=1e-6)


@pytest.mark.parametrize("stride", [2, 3, 4])
def test_backproject_with_a_stride_gives_the_full_result_on_that_grid(rng, stride):
    """With ``stride`` only every stride-th row and column is back-projected: exactly the points and (whole-image)
    pixel indices of the full back-projection on that grid, in the same order; a stride under 1 is refused."""
    cam = Camera(500.0, 505.0, 319.5, 239.5, 640, 479)  # an odd height: the last row is on the grid of 2
    depth = rng.uniform(0.5, 2.0, (479, 640)).astype(np.float32)
    depth[::7, ::5] = 0
    depth[3:9, 10:30] = np.nan
    pts, pix = cam.backproject(depth)
    v, u = np.divmod(pix, 640)
    on = (v % stride == 0) & (u % stride == 0)
    sp, spix = cam.backproject(depth, stride)
    assert np.array_equal(spix, pix[on]) and np.array_equal(sp, pts[on])
    with pytest.raises(ValueError, match="stride"):
        cam.backproject(depth, 0)


@pytest.mark.parametrize("scale", [1.0, 0.1, 0.2])
def test_depth_scale_round_trips_in_one_unit(tmp_path, scale):
    """depth_scale is mm per raw unit in memory and in files: to_dict/from_dict and a JSON file give the same
    camera back, and a raw value of 5000 is 5000 * scale mm."""
    import json

    cam = Camera(500.0, 501.0, 320.0, 240.0, 640, 480, scale)
    assert Camera.from_dict(cam.to_dict()) == cam
    (tmp_path / "c.json").write_text(json.dumps(cam.to_dict()))
    assert Camera.from_json(tmp_path / "c.json") == cam
    assert 5000 * cam.metres_per_unit == pytest.approx(5 * scale)


def test_open3d_intrinsics_depth_scale_is_units_per_metre(tmp_path):
    """Open3D's intrinsic JSON gives raw units per metre (1000 for mm): 1 mm per unit here."""
    import json

    (tmp_path / "o3d.json").write_text(json.dumps({"width": 640, "height": 480, "depth_scale": 5000.0,
                                                   "intrinsic_matrix": [525, 0, 0, 0, 525, 0, 319.5, 239.5, 1]}))
    cam = Camera.from_json(tmp_path / "o3d.json")
    assert (cam.fx, cam.cx, cam.cy) == (525.0, 319.5, 239.5) and cam.depth_scale == pytest.approx(0.2)
