"""Frames from depth PNGs and from clouds (organized or not, NaNs, OpenGL-style frames)."""
import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pcdet.camera import Camera
from pcdet.errors import InputError
from pcdet.frame import Frame
from pcdet.io.depth import write_depth_png

from .conftest import shared


def _cam_file(tmp_path, w=64, h=48, scale=1.0):
    p = tmp_path / "cam.json"
    p.write_text(json.dumps({"fx": 60, "fy": 60, "cx": w / 2, "cy": h / 2, "width": w, "height": h,
                             "depth_scale": scale}))
    return p


def test_depth_png_to_metres(tmp_path):
    raw = np.full((48, 64), 750, np.uint16)
    raw[0, 0] = 0
    write_depth_png(tmp_path / "d.png", raw)
    f = Frame.from_depth_png(tmp_path / "d.png", _cam_file(tmp_path))
    assert f.depth.dtype == np.float32 and f.depth[1, 1] == pytest.approx(0.75) and f.depth[0, 0] == 0
    assert len(f.points()[0]) == 48 * 64 - 1


def test_size_mismatch_names_file(tmp_path):
    write_depth_png(tmp_path / "d.png", np.full((40, 64), 700, np.uint16))
    with pytest.raises(InputError, match=r"d\.png: depth image is 64x40 but the camera is 64x48"):
        Frame.from_depth_png(tmp_path / "d.png", _cam_file(tmp_path))


@pytest.mark.parametrize("scale", [1000.0, 0.001])
def test_wrong_depth_scale_is_caught(tmp_path, scale):
    """mm PNG with a scale that makes it metres (1000 mm/unit), or micrometres (0.001 mm/unit)."""
    write_depth_png(tmp_path / "d.png", np.full((48, 64), 800, np.uint16))
    with pytest.raises(InputError, match=r"d\.png: median depth .* depth_scale is probably wrong"):
        Frame.from_depth_png(tmp_path / "d.png", _cam_file(tmp_path, scale=scale))


def test_empty_depth(tmp_path):
    write_depth_png(tmp_path / "d.png", np.zeros((48, 64), np.uint16))
    with pytest.raises(InputError, match="no valid"):
        Frame.from_depth_png(tmp_path / "d.png", _cam_file(tmp_path))


def test_frame_rejects_integer_depth():
    with pytest.raises(InputError, match="float metres"):
        Frame(np.zeros((4, 4), np.uint16), Camera(1, 1, 2, 2, 4, 4))


def test_unorganized_cloud_with_nan_and_inf_is_zbuffered(tmp_path):
    """An unorganized cloud of a tilted plane on a 2 mm grid at 0.98-1.02 m, with NaN and inf rows, plus a
    patch 5 cm behind part of it. Non-finite rows are dropped; the virtual camera's pitch matches the median
    spacing, so nearly every plane point gets a pixel of its own (>= 97 %; measured 98.6 %: the far side of
    the tilt is a little denser than one point per pixel) and back-projects to within half a pixel of itself
    (1.5 mm); the hidden patch loses every pixel to the plane in front (the z-buffer keeps the nearest)."""
    xs, ys = np.meshgrid(np.arange(-0.1, 0.1, 0.002), np.arange(-0.08, 0.08, 0.002))
    plane = np.stack([xs.ravel(), ys.ravel(), 1.0 + 0.2 * xs.ravel()], axis=1)
    bad = np.zeros(len(plane), bool)
    bad[::10] = True
    bad[5] = True
    plane[::10] = np.nan
    plane[5] = np.inf
    behind = plane[~bad][::7] * (1.05 / plane[~bad][::7, 2:3])  # same rays, 5 cm farther
    np.savetxt(tmp_path / "c.xyz", np.vstack([plane, behind]))
    f = Frame.from_cloud(tmp_path / "c.xyz")
    p, _ = f.points()
    good = plane[~bad]
    dist, idx = cKDTree(good).query(p)
    assert np.isfinite(p).all() and dist.max() < 0.0015 and p[:, 2].max() < 1.03
    assert len(np.unique(idx)) == len(p) >= 0.97 * len(good), (len(np.unique(idx)), len(p), len(good))


def test_empty_and_all_nan_clouds(tmp_path):
    (tmp_path / "e.xyz").write_text("")
    with pytest.raises(InputError, match=r"e\.xyz: point cloud is empty"):
        Frame.from_cloud(tmp_path / "e.xyz")
    np.savetxt(tmp_path / "n.xyz", np.full((10, 3), np.nan))
    with pytest.raises(InputError, match=r"n\.xyz: point cloud holds no finite point"):
        Frame.from_cloud(tmp_path / "n.xyz")


@pytest.mark.real
def test_organized_pcl_scene_recovers_kinect_intrinsics():
    """PCL's Kinect scene is organized and stored y-up/z-back; its pinhole is fitted to 0.01 px."""
    f = Frame.from_cloud(shared("pcl_milk") / "scene.pcd")
    assert f.camera.fx == pytest.approx(525.0, abs=0.01) and f.camera.cx == pytest.approx(319.5, abs=0.01)
    np.testing.assert_array_equal(np.diag(f.T_input_cam), [1, -1, -1, 1])
    assert (f.depth > 0).sum() == 241407  # every finite point kept, one per pixel


def test_bop_camera_entries_take_their_size_from_the_depth_image(tmp_path):
    """A BOP cam_K entry, and a whole scene_camera.json, carry no width/height: the depth image gives them. Alone
    (no image), such a file is refused with a sentence a person understands."""
    write_depth_png(tmp_path / "d.png", np.full((48, 64), 750, np.uint16))
    entry = {"cam_K": [60, 0, 32, 0, 60, 24, 0, 0, 1], "depth_scale": 1.0}
    (tmp_path / "entry.json").write_text(json.dumps(entry))
    (tmp_path / "scene_camera.json").write_text(json.dumps({"0": entry, "1": entry}))
    for cam in ("entry.json", "scene_camera.json"):
        f = Frame.from_depth_png(tmp_path / "d.png", tmp_path / cam)
        assert (f.camera.width, f.camera.height, f.camera.fx) == (64, 48, 60.0)
        assert f.depth[10, 10] == pytest.approx(0.75)
    with pytest.raises(InputError, match=r"entry\.json: camera JSON gives no image size \(width, height\)"):
        Camera.from_json(tmp_path / "entry.json")
    (tmp_path / "bad.json").write_text(json.dumps({"cam_K": [1, 2, 3]}))
    with pytest.raises(InputError, match=r"bad\.json: a camera matrix needs 9 numbers, got 3"):
        Frame.from_depth_png(tmp_path / "d.png", tmp_path / "bad.json")
