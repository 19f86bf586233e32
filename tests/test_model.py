"""Model library: formats, BOP folders, units, cache, bad files."""
import json
import shutil

import numpy as np
import pytest
import trimesh

from pcdet import model_cache
from pcdet.config import PipelineConfig
from pcdet.errors import InputError
from pcdet.io.models import UnitsWarning, resolve_scale
from pcdet.library import ModelLibrary
from pcdet.model_cache import load_model

from .conftest import MODELS, shared


def test_shipped_models_are_bop_folder(library):
    assert [m.obj_id for m in library] == [1, 2, 3, 4, 5, 6]
    info = json.loads((MODELS / "models_info.json").read_text())
    for m in library:
        assert m.name == info[str(m.obj_id)]["name"]
        assert m.diameter * 1000 == pytest.approx(info[str(m.obj_id)]["diameter"], rel=1e-3)  # mm -> m
        assert m.is_mesh and len(m.kp_points) == len(m.features) > 100
        # normals are outward: the mean of n . (p - centre) is positive for a closed solid
        assert ((m.points - m.points.mean(0)) * m.normals).sum(1).mean() > 0


@pytest.mark.real
def test_point_cloud_models_bop_mm():
    lib = ModelLibrary.from_folder(shared("ycbv_frame") / "models")
    assert [m.obj_id for m in lib] == [8, 14, 21]
    assert not lib[0].is_mesh
    assert lib.by_id(14).diameter == pytest.approx(0.1245, rel=0.02)  # 124.5 mm in models_info.json


def test_units_autodetected_and_warned(tmp_path):
    box_mm = trimesh.creation.box((80, 50, 30))
    box_mm.export(tmp_path / "box_mm.ply")
    m = load_model(tmp_path / "box_mm.ply", cache_dir=False)
    assert m.scale == 0.001 and "read as millimetres" in m.notes[0]
    assert m.diameter == pytest.approx(np.linalg.norm([0.08, 0.05, 0.03]), rel=0.02)
    # forced to metres, an 80-unit-wide part is warned about (building it at that size is not needed here)
    with pytest.warns(UnitsWarning, match=r"box_mm\.ply: model is 80\.0 m wide when read as m"):
        assert resolve_scale(box_mm.vertices, "m", tmp_path / "box_mm.ply", []) == 1.0


def test_bad_model_files(tmp_path):
    (tmp_path / "empty.ply").write_text("ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    with pytest.raises(InputError, match=r"empty\.ply"):
        load_model(tmp_path / "empty.ply", cache_dir=False)
    (tmp_path / "garbage.obj").write_text("this is not a mesh\n")
    with pytest.raises(InputError, match=r"garbage\.obj"):
        load_model(tmp_path / "garbage.obj", cache_dir=False)
    with pytest.raises(FileNotFoundError, match="missing.ply"):
        load_model(tmp_path / "missing.ply", cache_dir=False)
    with pytest.raises(InputError, match="no model files"):
        ModelLibrary.from_folder(_empty_dir(tmp_path))


def _empty_dir(tmp_path):
    d = tmp_path / "nothing_here"
    d.mkdir()
    return d


def test_mesh_without_faces_is_a_point_model(tmp_path, rng):
    pts = trimesh.creation.icosphere(subdivisions=4, radius=0.05).vertices
    trimesh.PointCloud(pts).export(tmp_path / "sphere_pts.ply")
    m = load_model(tmp_path / "sphere_pts.ply", cache_dir=False)
    assert not m.is_mesh and m.diameter == pytest.approx(0.1, rel=0.05)


def test_cache_hit_skips_building(tmp_path, monkeypatch):
    src = MODELS / "obj_000005.ply"
    shutil.copy(src, tmp_path / "part.ply")
    cfg = PipelineConfig()
    first = load_model(tmp_path / "part.ply", cfg, cache_dir=tmp_path / "cache")
    monkeypatch.setattr(model_cache, "build_model", lambda *a, **k: pytest.fail("cache was not used"))
    second = load_model(tmp_path / "part.ply", cfg, cache_dir=tmp_path / "cache")
    np.testing.assert_array_equal(first.features, second.features)
    np.testing.assert_array_equal(first.points, second.points)
    # a different parameter set is a different cache entry
    monkeypatch.undo()
    other = load_model(tmp_path / "part.ply", cfg.replace(features={"radius": 0.03}), cache_dir=tmp_path / "cache")
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 2 and other.features.shape[1] == 33


def test_cache_rebuilds_on_a_changed_file_and_on_a_corrupt_entry(tmp_path, monkeypatch):
    """The cache key is the file's bytes: an edited model is rebuilt (a new entry); a truncated entry is
    rebuilt in place and the result equals a fresh build."""
    shutil.copy(MODELS / "obj_000005.ply", tmp_path / "part.ply")
    cache = tmp_path / "cache"
    first = load_model(tmp_path / "part.ply", cache_dir=cache)
    (entry,) = cache.glob("*.npz")
    builds = []
    real_build = model_cache.build_model
    monkeypatch.setattr(model_cache, "build_model", lambda *a, **k: builds.append(1) or real_build(*a, **k))
    entry.write_bytes(entry.read_bytes()[:200])  # a crash mid-write on another system, say
    again = load_model(tmp_path / "part.ply", cache_dir=cache)
    assert builds == [1] and list(cache.glob("*.npz")) == [entry]
    np.testing.assert_array_equal(again.features, first.features)
    load_model(tmp_path / "part.ply", cache_dir=cache)
    assert builds == [1]  # the rebuilt entry is used
    mesh = trimesh.load(tmp_path / "part.ply", process=False)
    mesh.apply_scale(1.5)
    mesh.export(tmp_path / "part.ply")
    bigger = load_model(tmp_path / "part.ply", cache_dir=cache)
    assert builds == [1, 1] and len(list(cache.glob("*.npz"))) == 2
    assert bigger.diameter == pytest.approx(1.5 * first.diameter, rel=1e-6)


@pytest.mark.parametrize("size, words", [(80000.0, "80000 units wide, 80 m when read as millimetres"),
                                         (0.001, "0.001 units wide, 1 mm when read as metres")])
def test_implausible_sizes_are_refused_unless_units_are_given(tmp_path, size, words):
    """An 80 m or a 1 mm 'object' means the units are not what they seem: refused in auto mode, read when
    the units are given (the 80 m one with a warning)."""
    trimesh.creation.box((size, size / 2, size / 3)).export(tmp_path / "b.ply")
    with pytest.raises(InputError, match=words):
        load_model(tmp_path / "b.ply", cache_dir=False)
    models = __import__("pcdet.io.models", fromlist=["load_geometry"])
    if size > 1:  # read as asked, with a warning: 80 m is larger than any object
        with pytest.warns(models.UnitsWarning, match="80.0 m wide when read as mm"):
            assert models.load_geometry(tmp_path / "b.ply", units="mm").vertices.shape[1] == 3
    else:
        assert models.load_geometry(tmp_path / "b.ply", units="m").vertices.shape[1] == 3
