"""pcdet from Python with data in memory: numpy arrays, open3d and trimesh geometries where paths go; short
reprs; the package's own help."""
import numpy as np
import pytest
import trimesh

import pcdet
from pcdet.errors import InputError

from .conftest import random_pose


def test_register_takes_arrays_and_open3d_clouds(rng):
    """A box's surface moved by a known pose, given as an open3d cloud, is found from the box as a trimesh
    mesh, and from the box's samples as an (N, 3) array, within 2 mm."""
    from pcdet._o3d import o3d

    box = trimesh.creation.box((0.12, 0.08, 0.05))
    box.vertices[:, 0] += 0.3 * box.vertices[:, 1]  # a slanted box: no symmetry to confuse the pose
    T = random_pose(rng, 0.05)
    pts, _ = trimesh.sample.sample_surface_even(box, 6000, seed=3)
    scan = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(pts) @ T[:3, :3].T + T[:3, 3]))
    for source in (box, np.asarray(pts)):
        r = pcdet.register(source, scan)
        moved = np.asarray(box.vertices) @ r.T_target_source[:3, :3].T + r.T_target_source[:3, 3]
        truth = np.asarray(box.vertices) @ T[:3, :3].T + T[:3, 3]
        assert np.abs(moved - truth).max() < 0.002
    with pytest.raises(InputError, match=r"source: expected a file path, an \(N, 3\) array"):
        pcdet.register({"not": "geometry"}, scan)
    with pytest.raises(InputError, match=r"source: points must be an \(N, 3\) array, got shape \(5, 2\)"):
        pcdet.register(np.zeros((5, 2)), scan)


def test_frames_from_arrays_and_a_library_from_meshes_detect_an_object():
    """A library built from a trimesh mesh finds it in a frame built from an organized (H, W, 3) array (the part
    floats in front of the camera: there is no table, so no plane to remove)."""
    from pcdet.render import render_meshes
    from pcdet.synth import KINECT

    part = trimesh.creation.annulus(0.03, 0.05, 0.04)
    cfg = pcdet.PipelineConfig().replace(preprocess={"remove_plane": False})
    lib = pcdet.ModelLibrary.from_objects({"ring": part}, cfg)
    T = np.eye(4)
    T[:3, :3] = trimesh.transformations.rotation_matrix(0.9, [1, 0.3, 0])[:3, :3]
    T[2, 3] = 0.7
    depth = render_meshes(KINECT, [(part.vertices, part.faces, T)]).depth
    pts, pix = KINECT.backproject(depth)
    grid = np.full((KINECT.height * KINECT.width, 3), np.nan)
    grid[pix] = pts
    frame = pcdet.Frame.from_cloud(grid.reshape(KINECT.height, KINECT.width, 3))
    res = pcdet.Detector(lib, cfg).detect(frame, {1: 1})
    assert len(res.detections) == 1 and np.linalg.norm(res.detections[0].T_cam_model[:3, 3] - T[:3, 3]) < 0.01


def test_reprs_are_short_and_useful(synth_small, library):
    from pcdet.datasets.bop import BopDataset

    ds = BopDataset(synth_small)
    f = ds.frame(ds.images[0])
    det = pcdet.Detector(library, workers=1)
    res = det.detect(f)
    for text in (repr(f), repr(library), repr(det), repr(res), repr(res.detections[0]), repr(library[0])):
        assert len(text) < 200 and "array(" not in text, text
    assert repr(f).startswith("Frame(640x480,") and "depth 0." in repr(f)
    assert repr(library).startswith("ModelLibrary(6 models: bracket (1)")
    assert repr(det) == "Detector(6 models, grouping='ransac', selection='global', workers=1)"
    assert repr(res).startswith(f"DetectionResult({len(res.detections)} detection(s): ")


def test_every_public_name_has_a_docstring_and_help_gives_a_tour():
    undocumented = [n for n in pcdet.__all__ if n != "__version__" and not (getattr(pcdet, n).__doc__ or "").strip()]
    assert not undocumented
    assert "pcdet.Detector" in pcdet.__doc__ and ">>>" in pcdet.__doc__ and len(pcdet.__doc__.splitlines()) < 40
