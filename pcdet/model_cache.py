"""Built models kept on disk, keyed by the model file's bytes, its units and id, and every parameter that
shapes a model; a stale or corrupt entry is rebuilt."""
from __future__ import annotations

import hashlib
import io
import json
import os
import warnings
import zipfile
from pathlib import Path

import numpy as np

from .config import PipelineConfig
from .io.atomic import atomic_write_bytes
from .io.models import UnitsWarning
from .model import ObjectModel, build_model

# 14: SHOT frames turned by a rule that does not depend on the eigen-solver's sign (pcdet.lrf); 13: normals by pcdet's
# kernel; 12: FPFH by pcdet's kernel (neighbours at equal distance by index); 11: FPFH from
# open3d's double-precision implementation; 10: normals by orient_along_surface
CACHE_VERSION = 14


def _hash_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _model_params(cfg: PipelineConfig) -> dict:
    return {"voxel": cfg.preprocess.voxel, "normal_radius": cfg.preprocess.normal_radius,
            "normal_max_nn": cfg.preprocess.normal_max_nn, "keypoints": vars(cfg.keypoints),
            "features": vars(cfg.features), "model": vars(cfg.model), "version": CACHE_VERSION}


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/pcdet/models`` (default ``~/.cache/pcdet/models``)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "pcdet" / "models"


def _save(model: ObjectModel, path: Path) -> None:
    buf = io.BytesIO()
    meta = {k: getattr(model, k) for k in ("name", "obj_id", "path", "diameter", "scale", "notes")}
    arrays = {k: getattr(model, k) for k in ("points", "normals", "kp_points", "kp_normals", "features", "kp_lrfs")}
    if model.is_mesh:
        arrays.update(vertices=model.vertices, faces=model.faces)
    if model.kp_colors is not None:
        arrays.update(kp_colors=model.kp_colors)
    np.savez(buf, meta=np.array(json.dumps(meta)), **arrays)
    atomic_write_bytes(path, buf.getvalue())


def _load(path: Path) -> ObjectModel:
    with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        arrays = {k: z[k] for k in z.files if k != "meta"}
    return ObjectModel(**meta, **arrays)


def load_model(path, cfg: PipelineConfig | None = None, *, units="auto", obj_id: int = 0, name: str | None = None,
               cache_dir: Path | str | None | bool = None) -> ObjectModel:
    """A model, from the on-disk cache when the file's bytes and the parameters are unchanged.

    ``cache_dir=False`` disables the cache; ``None`` uses ``$XDG_CACHE_HOME/pcdet/models``.
    """
    cfg = cfg or PipelineConfig()
    path = Path(path)
    if cache_dir is False:
        return build_model(path, cfg, units=units, obj_id=obj_id, name=name)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: model file not found")
    key_src = json.dumps({"file": _hash_file(path), "units": units, "obj_id": int(obj_id), "name": name,
                          "params": _model_params(cfg)}, sort_keys=True, default=str)
    key = hashlib.sha256(key_src.encode()).hexdigest()[:24]
    cdir = Path(cache_dir) if cache_dir else default_cache_dir()
    cpath = cdir / f"{path.stem}-{key}.npz"
    if cpath.is_file():
        try:
            m = _load(cpath)
            m.path = str(path)
            return m
        except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile):
            pass  # a corrupt (truncated: BadZipFile) or stale (other fields) cache entry is rebuilt below
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = build_model(path, cfg, units=units, obj_id=obj_id, name=name)
    for w in caught:  # re-emit so callers see them on this first (uncached) load ...
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    m.notes.extend(str(w.message) for w in caught if issubclass(w.category, UnitsWarning))  # ... and later ones
    try:
        _save(m, cpath)
    except OSError:
        pass  # a read-only cache location only costs speed
    return m
