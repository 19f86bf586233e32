"""Recording readers: each format read from files written here (or shipped in ../shared/data), the same frames
and poses coming back, auto-detection, and a clear error for an unknown layout."""
import json
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pcdet.datasets import READERS, FrameRef, Recording, detect_format, open_recording
from pcdet.errors import InputError
from pcdet.io.depth import write_depth_png, write_png
from pcdet.synth import SynthConfig, synthesize

from .conftest import shared


@pytest.fixture(scope="module")
def sequence(tmp_path_factory, library):
    """A 6-frame synthetic recording of one scene (BOP layout)."""
    out = tmp_path_factory.mktemp("seq")
    return synthesize(library, out, SynthConfig(scenes=1, objects=3, sequence=6, seed=4))


@pytest.mark.slow
def test_bop_sequence_has_smooth_camera_poses_and_consistent_ground_truth(sequence):
    rec = open_recording(sequence)
    assert rec.format == "bop" and isinstance(rec, Recording) and len(rec) == 6
    poses = rec.camera_poses()
    refs = list(rec)
    for a, b in zip(refs, refs[1:]):
        rel = np.linalg.inv(poses[a]) @ poses[b]
        assert 0.002 < np.linalg.norm(rel[:3, 3]) < 0.2  # the camera moves, smoothly (90 deg over 6 frames)
        assert np.degrees(Rotation.from_matrix(rel[:3, :3]).magnitude()) < 25
    # each object stays put in the world: T_world_cam @ T_cam_obj is the same in every frame (1e-6 m)
    first = [poses[refs[0]] @ g["T_cam_model"] for g in rec.gt(refs[0])]
    for r in refs[1:]:
        for T0, g in zip(first, rec.gt(r)):
            assert np.allclose(poses[r] @ g["T_cam_model"], T0, atol=1e-6)


def _write_tum(root, rec):
    """``rec``'s frames as a TUM recording: depth in 1/5000 m, stamps 1/30 s apart, rgb stamps 5 ms later, and
    groundtruth.txt with the camera poses as quaternions."""
    (root / "depth").mkdir(parents=True)
    (root / "rgb").mkdir()
    poses = rec.camera_poses()
    dl, rl, gl = ["# depth"], ["# rgb"], ["# timestamp tx ty tz qx qy qz qw"]
    for k, ref in enumerate(rec):
        f = rec.frame(ref)
        t = 1000.0 + k / 30
        write_depth_png(root / "depth" / f"{t:.6f}.png", np.rint(f.depth * 5000).astype(np.uint16))
        write_png(root / "rgb" / f"{t + 0.005:.6f}.png", f.rgb)
        dl.append(f"{t:.6f} depth/{t:.6f}.png")
        rl.append(f"{t + 0.005:.6f} rgb/{t + 0.005:.6f}.png")
        T = poses[ref]
        q = Rotation.from_matrix(T[:3, :3]).as_quat()
        gl.append(f"{t + 0.001:.6f} " + " ".join(f"{v:.9f}" for v in [*T[:3, 3], *q]))
    (root / "depth.txt").write_text("\n".join(dl) + "\n")
    (root / "rgb.txt").write_text("\n".join(rl) + "\n")
    (root / "groundtruth.txt").write_text("\n".join(gl) + "\n")
    cam = rec.frame(rec.images[0]).camera
    (root / "camera.json").write_text(json.dumps({**cam.to_dict(), "depth_scale": 0.2}))


def test_tum_reader_gives_back_depth_rgb_and_poses(tmp_path, sequence):
    bop = open_recording(sequence)
    _write_tum(tmp_path / "tum", bop)
    rec = open_recording(tmp_path / "tum")
    assert rec.format == "tum" and len(rec) == 6
    assert rec.images[1].timestamp == pytest.approx(1000 + 1 / 30)
    gt = rec.camera_poses()
    for ref, bref in zip(rec, bop):
        f, b = rec.frame(ref), bop.frame(bref)
        assert np.abs(f.depth - b.depth).max() <= 1e-4 + 1e-7  # 1 mm PNG re-quantised at 0.2 mm
        assert np.array_equal(f.rgb, b.rgb)
        assert np.allclose(gt[ref], bop.camera_poses()[bref], atol=1e-6)


def test_tum_without_camera_file_uses_the_documented_default(tmp_path, sequence):
    _write_tum(tmp_path / "tum", open_recording(sequence))
    (tmp_path / "tum" / "camera.json").unlink()
    rec = open_recording(tmp_path / "tum")
    assert (rec.camera.fx, rec.camera.cx, rec.camera.depth_scale) == (525.0, 319.5, 0.2)


def test_folder_and_cloud_readers(tmp_path, sequence):
    bop = open_recording(sequence)
    root = tmp_path / "plain"
    (root / "depth").mkdir(parents=True)
    clouds = tmp_path / "clouds"
    clouds.mkdir()
    for ref in list(bop)[:3]:
        f = bop.frame(ref)
        write_depth_png(root / "depth" / f"{ref.im_id:04d}.png", np.rint(f.depth * 1000).astype(np.uint16))
        pts, _ = f.points()
        np.savetxt(clouds / f"{ref.im_id:04d}.xyz", pts[::7], fmt="%.6f")
    (root / "camera.json").write_text(json.dumps(f.camera.to_dict() | {"depth_scale": 1.0}))
    rec = open_recording(root)
    assert rec.format == "folder" and len(rec) == 3 and rec.frame(rec.images[0]).rgb is None
    assert np.abs(rec.frame(rec.images[2]).depth - f.depth).max() < 1e-6
    crec = open_recording(clouds)
    assert crec.format == "clouds" and len(crec) == 3
    assert len(crec.frame(crec.images[0]).points()[0]) > 1000


@pytest.mark.real
def test_redwood_layout_of_the_open3d_sample(tmp_path):
    """The Open3D sample: 5 frames with colour and the PrimeSense intrinsics; the camera poses are
    trajectory.log's matrices, and they are T_world_cam: frame 4's points moved by inv(P0) P4 land on frame 0's
    (median 6.0 mm, 97 % within 2 cm; unmoved: 20.9 mm, 48 %)."""
    from scipy.spatial import cKDTree

    from pcdet.datasets.redwood import read_log

    d = shared("open3d_rgbd")
    rec = open_recording(d)
    assert rec.format == "redwood" and len(rec) == 5
    f = rec.frame(rec.images[0])
    assert f.rgb is not None and f.camera.fx == 525.0 and f.camera.cx == 319.5
    poses = rec.camera_poses()
    log = read_log(d / "trajectory.log")
    assert len(poses) == 5 and all(np.array_equal(poses[r], T) for r, T in zip(rec, log))
    p0 = rec.frame(rec.images[0]).points()[0][::4]
    p4 = rec.frame(rec.images[4]).points()[0][::4]
    T = np.linalg.inv(poses[rec.images[0]]) @ poses[rec.images[4]]
    dist, _ = cKDTree(p0).query(p4 @ T[:3, :3].T + T[:3, 3])
    assert np.median(dist) < 0.01 and (dist < 0.02).mean() > 0.9


def test_unknown_layout_names_the_known_ones(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(InputError) as e:
        detect_format(tmp_path)
    assert str(tmp_path) in str(e.value) and all(name in str(e.value) for name in READERS)
    with pytest.raises(FileNotFoundError):
        open_recording(tmp_path / "missing")


def test_frame_refs_sort_by_scene_then_image():
    assert sorted([FrameRef(2, 0), FrameRef(1, 5), FrameRef(1, 2)]) == [FrameRef(1, 2), FrameRef(1, 5),
                                                                         FrameRef(2, 0)]


def test_folder_recording_with_a_bop_camera_entry(tmp_path, sequence):
    """A plain folder whose camera.json is a BOP cam_K entry (no size) reads its frames at the PNGs' size."""
    bop = open_recording(sequence)
    root = tmp_path / "plain"
    (root / "depth").mkdir(parents=True)
    f = bop.frame(bop.images[0])
    write_depth_png(root / "depth" / "0000.png", np.rint(f.depth * 1000).astype(np.uint16))
    (root / "camera.json").write_text(json.dumps({"cam_K": f.camera.K.reshape(-1).tolist(), "depth_scale": 1.0}))
    rec = open_recording(root)
    g = rec.frame(rec.images[0])
    assert (g.camera.width, g.camera.height) == (f.camera.width, f.camera.height)
    assert np.abs(g.depth - f.depth).max() < 1e-6


@pytest.mark.real
def test_sevenscenes_layout_reads_depth_in_mm_and_camera_to_world_poses():
    """The 7-Scenes clip: auto-detected, 300 frames, Kinect intrinsics from camera-intrinsics.txt, depth in metres
    (a Kinect sees this room at 0.5-4 m), and the .pose.txt matrices are T_world_cam: frame 40's points moved by
    inv(P0) P40 land on frame 0's (median 6.8 mm; unmoved 71 mm)."""
    from scipy.spatial import cKDTree

    d = shared("sevenscenes")
    rec = open_recording(d)
    assert rec.format == "7scenes" and len(rec) == 300
    f0 = rec.frame(rec.images[0])
    assert (f0.camera.fx, f0.camera.cx, f0.camera.width, f0.camera.height) == (585.0, 320.0, 640, 480)
    z = f0.depth[f0.depth > 0]
    assert 0.3 < np.median(z) < 4.0 and z.max() < 10.0
    poses = rec.camera_poses()
    assert len(poses) == 300
    P0, P40 = poses[rec.images[0]], poses[rec.images[40]]
    assert np.allclose(P0[:3, :3] @ P0[:3, :3].T, np.eye(3), atol=1e-3)  # KinectFusion's, printed to 8 digits
    p0 = f0.points()[0][::4]
    p40 = rec.frame(rec.images[40]).points()[0][::4]
    T = np.linalg.inv(P0) @ P40
    moved, _ = cKDTree(p0).query(p40 @ T[:3, :3].T + T[:3, 3])
    unmoved, _ = cKDTree(p0).query(p40)
    assert np.median(moved) < 0.012 and np.median(unmoved) > 0.04


@pytest.mark.real
def test_sevenscenes_scene_folder_reads_each_sequence_as_a_scene(tmp_path):
    """A scene folder as 7-Scenes ships it (``chess/seq-01``, ``chess/seq-02``, the intrinsics beside them): each
    ``seq-NN`` is scene NN, its frames numbered from 0 in file-number order and read from its own folder, with its
    own poses; two folders with one number are refused, naming both."""
    src = shared("sevenscenes")
    scene = tmp_path / "chess"
    for seq, frames in (("seq-02", (0, 2, 4)), ("seq-01", (10, 11))):  # made out of order: read in number order
        (scene / seq).mkdir(parents=True)
        for i in frames:
            for kind in ("depth.png", "pose.txt"):
                shutil.copy(src / f"frame-{i:06d}.{kind}", scene / seq / f"frame-{i:06d}.{kind}")
    K = np.array([[500.0, 0, 321], [0, 501, 239], [0, 0, 1]])
    (scene / "camera-intrinsics.txt").write_text("\n".join(" ".join(map(str, r)) for r in K))
    rec = open_recording(scene)
    assert rec.format == "7scenes"
    assert [(r.scene_id, r.im_id) for r in rec] == [(1, 0), (1, 1), (2, 0), (2, 1), (2, 2)]
    assert rec.source(rec.images[1]).endswith("seq-01/frame-000011.depth.png")
    assert rec.source(rec.images[4]).endswith("seq-02/frame-000004.depth.png")
    f = rec.frame(rec.images[4])
    assert (f.camera.fx, f.camera.fy, f.camera.cx, f.camera.width) == (500.0, 501.0, 321.0, 640)
    flat = open_recording(src)
    assert f.info["frame"] == 4 and np.array_equal(f.depth, flat.frame(flat.images[4]).depth)
    poses = rec.camera_poses()
    assert np.allclose(poses[rec.images[2]], np.loadtxt(src / "frame-000000.pose.txt"))
    (scene / "seq-2").mkdir()
    with pytest.raises(InputError) as e:
        open_recording(scene)
    assert "seq-02 and seq-2 are both sequence 2" in str(e.value)


def test_sevenscenes_bad_pose_file_names_the_file(tmp_path):
    """A 7-Scenes folder written here: frames in file-number order, and a pose file that is not 4x4 is refused
    with its name; without camera-intrinsics.txt the documented Kinect default is used."""
    for i in (0, 1, 2):
        write_depth_png(tmp_path / f"frame-{i:06d}.depth.png", np.full((48, 64), 1500 + i, np.uint16))
        (tmp_path / f"frame-{i:06d}.pose.txt").write_text("\n".join(" ".join(map(str, r)) for r in np.eye(4)))
    rec = open_recording(tmp_path)
    assert rec.format == "7scenes" and len(rec) == 3
    assert rec.camera.fx == 585.0 and (rec.camera.width, rec.camera.height) == (64, 48)
    assert np.allclose(rec.frame(rec.images[2]).depth, 1.502)
    (tmp_path / "frame-000001.pose.txt").write_text("1 0 0\n0 1 0\n")
    with pytest.raises(InputError) as e:
        rec.camera_poses()
    assert "frame-000001.pose.txt" in str(e.value) and "4x4" in str(e.value)


def test_sevenscenes_colour_as_jpg_or_as_3dmatch_png(tmp_path):
    """7-Scenes ships ``frame-N.color.jpg``, 3DMatch's RGB-D sequences ``frame-N.color.png``: either is the frame's
    colour (the JPG where both are), and one whose size differs from the depth's is left out."""
    for i in (0, 1, 2):
        write_depth_png(tmp_path / f"frame-{i:06d}.depth.png", np.full((48, 64), 1500, np.uint16))
    write_png(tmp_path / "frame-000000.color.png", np.full((48, 64, 3), (200, 10, 10), np.uint8))
    write_png(tmp_path / "frame-000001.color.png", np.full((24, 32, 3), 50, np.uint8))
    write_png(tmp_path / "frame-000002.color.png", np.full((48, 64, 3), 50, np.uint8))
    write_png(tmp_path / "frame-000002.color.jpg", np.full((48, 64, 3), (10, 200, 10), np.uint8))
    rec = open_recording(tmp_path)
    f0, f1, f2 = (rec.frame(ref) for ref in rec.images)
    assert f0.rgb is not None and tuple(f0.rgb[5, 5]) == (200, 10, 10)
    assert f1.rgb is None
    assert f2.rgb is not None and f2.rgb[5, 5, 1] > 150  # the JPG's green, not the PNG's grey


@pytest.mark.real
def test_bop_depth_and_grey_as_tiff(tmp_path):
    """A BOP split whose images are 16-bit TIFFs (ITODD ships ``depth/*.tif`` and ``gray/*.tif``): the YCB-V frame
    with its depth PNG rewritten as a TIFF and its colour as a grey TIFF reads the same depth, in metres."""
    from PIL import Image

    from pcdet.io.depth import read_depth_png

    src = shared("ycbv_frame")
    shutil.copytree(src / "test", tmp_path / "test")
    scene = tmp_path / "test" / "000001"
    raw = read_depth_png(scene / "depth" / "000001.png")
    (scene / "depth" / "000001.png").unlink()
    Image.fromarray(raw).save(scene / "depth" / "000001.tif")
    shutil.rmtree(scene / "rgb")
    (scene / "gray").mkdir()
    Image.fromarray(np.full(raw.shape, 128, np.uint8)).save(scene / "gray" / "000001.tif")
    want = open_recording(src)
    rec = open_recording(tmp_path)
    f, g = rec.frame(rec.images[0]), want.frame(want.images[0])
    assert rec.source(rec.images[0]).endswith("depth/000001.tif")
    assert np.array_equal(f.depth, g.depth) and 0.3 < np.median(f.depth[f.depth > 0]) < 2.0
    assert f.rgb is not None and f.rgb.shape[:2] == raw.shape
