"""The model library: the objects pcdet looks for, read from a folder (BOP ``models/`` included) or files."""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator

from .config import PipelineConfig
from .errors import InputError
from .io.jsonfile import read_json
from .io.models import MODEL_SUFFIXES
from .model import ObjectModel, build_model
from .model_cache import load_model


class ModelLibrary:
    """An ordered list of ``ObjectModel`` with unique ids and lookup by id."""

    def __init__(self, models: list[ObjectModel]):
        if not models:
            raise InputError("model library is empty")
        ids = [m.obj_id for m in models]
        if len(set(ids)) != len(ids):
            raise InputError(f"model ids are not unique: {ids}")
        self.models = list(models)

    def __len__(self) -> int:
        return len(self.models)

    def __iter__(self) -> Iterator[ObjectModel]:
        return iter(self.models)

    def __getitem__(self, i: int) -> ObjectModel:
        return self.models[i]

    def __repr__(self) -> str:
        names = ", ".join(f"{m.name} ({m.obj_id})" for m in self.models[:6])
        more = f", ... {len(self) - 6} more" if len(self) > 6 else ""
        return f"ModelLibrary({len(self)} models: {names}{more})"

    def by_id(self, obj_id: int) -> ObjectModel:
        """The model with BOP id ``obj_id`` (``KeyError`` when none)."""
        for m in self.models:
            if m.obj_id == obj_id:
                return m
        raise KeyError(f"no model with obj_id {obj_id}")

    def index_of(self, obj_id: int) -> int:
        """Position of the model with ``obj_id`` in the library."""
        for i, m in enumerate(self.models):
            if m.obj_id == obj_id:
                return i
        raise KeyError(f"no model with obj_id {obj_id}")

    @property
    def notes(self) -> list[str]:
        """What loading the models noted (units detected, warnings), model by model."""
        return [n for m in self.models for n in m.notes]

    @classmethod
    def from_folder(cls, folder, cfg: PipelineConfig | None = None, *, units="auto",
                    cache_dir: Path | str | None | bool = None,
                    progress: Callable[[str], None] | None = None) -> "ModelLibrary":
        """Every model file in ``folder`` (sorted by name). A BOP ``models/`` folder (``models_info.json``
        beside ``obj_NNNNNN.ply``) keeps its ids and is read in millimetres unless ``units`` says otherwise;
        elsewhere ids are 1, 2, ... in file-name order and units are auto-detected."""
        folder = Path(folder)
        if not folder.is_dir():
            raise FileNotFoundError(f"{folder}: model folder not found")
        info_path = folder / "models_info.json"
        info = read_json(info_path) if info_path.is_file() else {}
        files = sorted(p for p in folder.iterdir() if p.suffix.lower() in MODEL_SUFFIXES and p.is_file())
        if not files:
            raise InputError(f"no model files ({', '.join(sorted(MODEL_SUFFIXES))})", folder)
        models = []
        for i, p in enumerate(files, start=1):
            obj_id, name, u = i, p.stem, units
            if info and p.stem.startswith("obj_") and p.stem[4:].isdigit():
                obj_id = int(p.stem[4:])
                entry = info.get(str(obj_id), {})
                name = entry.get("name", p.stem)
                u = "mm" if units in (None, "auto") else units
            if progress:
                progress(name)
            models.append(load_model(p, cfg, units=u, obj_id=obj_id, name=name, cache_dir=cache_dir))
        return cls(models)

    @classmethod
    def from_path(cls, path, cfg: PipelineConfig | None = None, *, units="auto",
                  cache_dir: Path | str | None | bool = None, progress=None) -> "ModelLibrary":
        """A folder of models (``from_folder``) or a single model file (id 1)."""
        path = Path(path)
        if path.is_file():
            return cls.from_files([path], cfg, units=units, cache_dir=cache_dir)
        return cls.from_folder(path, cfg, units=units, cache_dir=cache_dir, progress=progress)

    @classmethod
    def from_objects(cls, objects: dict, cfg: PipelineConfig | None = None, *, units="auto") -> "ModelLibrary":
        """Models held in memory, ``{name: geometry}``: an (N, 3) array of points, an open3d ``PointCloud`` or
        ``TriangleMesh``, or a trimesh object (metres, or ``units``). Ids are 1, 2, ... in the order given; they
        are built here and not cached.

        >>> import trimesh
        >>> lib = ModelLibrary.from_objects({"box": trimesh.creation.box((0.08, 0.05, 0.03))})
        """
        cfg = cfg or PipelineConfig()
        return cls([build_model(g, cfg, units=units, obj_id=i, name=str(n))
                    for i, (n, g) in enumerate(objects.items(), start=1)])

    @classmethod
    def from_files(cls, paths, cfg: PipelineConfig | None = None, *, units="auto", cache_dir=None) -> "ModelLibrary":
        """The given model files, ids 1, 2, ... in the order given."""
        return cls([load_model(p, cfg, units=units, obj_id=i, cache_dir=cache_dir)
                    for i, p in enumerate(paths, start=1)])
