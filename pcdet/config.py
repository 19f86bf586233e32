"""Pipeline parameters: one frozen dataclass per stage (each defined in its stage's module), composed here
into ``PipelineConfig`` and read from TOML.

Lengths are metres. Every field carries its one-line documentation (``params.param``), which ``dump_toml``
writes as a comment; ``pipelines/default.toml`` sets every field to the defaults below (a test checks). The
grouping section nests one table per grouper of the registry (``[grouping.ransac]``, ``[grouping.hough]``,
...), each the grouper's own ``Config``. Values are type-checked when read: a float where an integer belongs,
or a string where a boolean belongs, is refused with the file, the field and the expected type.
"""
from __future__ import annotations

import dataclasses
import sys
import typing
from dataclasses import dataclass
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from .errors import ConfigError, InputError
from .features import FeatureConfig
from .grouping import GroupingConfig
from .keypoints import KeypointConfig
from .matching import MatchingConfig
from .model_views import ModelConfig
from .odometry import OdometryConfig
from .params import param
from .preprocess import PreprocessConfig
from .refine import RefineConfig
from .resources import shipped
from .verify import VerifyConfig

__all__ = ["FeatureConfig", "GroupingConfig", "KeypointConfig", "MatchingConfig", "ModelConfig", "PipelineConfig",
           "PreprocessConfig", "RefineConfig", "VerifyConfig", "dump_toml", "field_docs", "load_pipeline"]

PIPELINES_DIR = shipped("pipelines")


@dataclass(frozen=True)
class PipelineConfig:
    """Every parameter of the detector; ``seed`` drives every random step."""

    seed: int = param(0, "seed of every random step (plane RANSAC, grouping); same input + config + seed = same "
                         "output")
    preprocess: PreprocessConfig = param(PreprocessConfig, "depth crop, voxel grid, plane, clusters, normals")
    model: ModelConfig = param(ModelConfig, "how model descriptors are made")
    keypoints: KeypointConfig = param(KeypointConfig, "scene and model keypoints")
    features: FeatureConfig = param(FeatureConfig, "FPFH and local reference frames")
    matching: MatchingConfig = param(MatchingConfig, "descriptor matching")
    grouping: GroupingConfig = param(GroupingConfig, "correspondence grouping")
    refine: RefineConfig = param(RefineConfig, "ICP refinement")
    verify: VerifyConfig = param(VerifyConfig, "verification against the depth, and selection")

    def to_dict(self) -> dict:
        """Every field as nested dicts (what result files record as ``pipeline``)."""
        return dataclasses.asdict(self)

    def replace(self, **changes) -> "PipelineConfig":
        """Copy with some fields changed, sections given as dicts (nested for sub-tables):
        ``cfg.replace(seed=3, grouping={"method": "hough", "hough": {"bin": 0.02}})``."""
        return _replace(self, changes)

    @classmethod
    def from_dict(cls, data: dict, source: str | None = None) -> "PipelineConfig":
        """A config from nested dicts (as TOML reads them); unknown or mistyped fields raise ``ConfigError``
        naming ``source``, the field and what was expected."""
        return _from_table(cls, data, source, "")


def _replace(obj, changes: dict):
    new = {}
    for k, v in changes.items():
        cur = getattr(obj, k)
        new[k] = _replace(cur, v) if isinstance(v, dict) and dataclasses.is_dataclass(cur) else v
    return dataclasses.replace(obj, **new)


# fields that moved when every grouper got a section of its own
MOVED = {f"grouping.{k}": f"grouping.ransac.{k}" for k in
         ("iterations", "max_instances", "alternatives", "rescore", "min_normal_spread_deg")}
MOVED.update({f"grouping.{k}": f"grouping.ransac.{k} and grouping.gc.{k}"
              for k in ("edge_tolerance", "normal_tolerance_deg")})
MOVED.update({"grouping.hough_bin": "grouping.hough.bin", "grouping.hough_min_votes": "grouping.hough.min_votes",
              "grouping.hough_rotation_tol_deg": "grouping.hough.rotation_tol_deg"})

_TYPE_NAMES = {bool: "a boolean (true or false)", int: "an integer", float: "a number", str: "a string"}


def _from_table(cls, table: dict, source, path: str):
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = [k for k in table if k not in names]
    if unknown:
        moved = [f"{path}.{k} is now {MOVED[f'{path}.{k}']}" for k in unknown if f"{path}.{k}" in MOVED]
        where = f"in [{path}]" if path else "at the top level"
        what = f"unknown pipeline section {unknown[0]!r}" if not path and len(unknown) == 1 \
            else f"unknown field(s) {sorted(unknown)} {where}"
        hint = f" ({'; '.join(moved)})" if moved else f"; known: {sorted(names)}"
        raise ConfigError(what + hint, source)
    kwargs = {}
    for key, value in table.items():
        name = f"{path}.{key}" if path else key
        typ = hints[key]
        if dataclasses.is_dataclass(typ):
            if not isinstance(value, dict):
                raise ConfigError(f"[{name}] must be a table", source)
            kwargs[key] = _from_table(typ, value, source, name)
        else:
            kwargs[key] = _typed(value, typ, name, source)
    try:
        return cls(**kwargs)
    except ConfigError as e:
        raise ConfigError(f"[{path}]: {e.problem}" if path else e.problem, source) from None


def _typed(value, typ, name: str, source):
    ok = isinstance(value, typ) and not (typ is not bool and isinstance(value, bool))
    if typ is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if not ok:
        raise ConfigError(f"{name} = {value!r}: expected {_TYPE_NAMES.get(typ, typ.__name__)}", source)
    return value


def _is_path(name_or_path: str | Path) -> bool:
    """A ``Path``, or a string with a suffix or a folder in it (``./hough.toml``, ``cfg/mine``), names a file; a
    bare word (``hough``) names a shipped preset, whatever the current folder holds."""
    if isinstance(name_or_path, Path):
        return True
    return bool(Path(name_or_path).suffix) or "/" in name_or_path or "\\" in name_or_path


def _preset_path(name_or_path: str | Path) -> Path:
    """A pipeline file: a path as given (see ``_is_path``), else the shipped preset ``pipelines/<name>.toml``."""
    if _is_path(name_or_path):
        p = Path(name_or_path)
        if not p.is_file():
            raise FileNotFoundError(f"{p}: pipeline file not found")
        return p
    preset = PIPELINES_DIR / f"{name_or_path}.toml"
    if preset.is_file():
        return preset
    names = sorted(q.stem for q in PIPELINES_DIR.glob("*.toml"))
    raise FileNotFoundError(f"{name_or_path}: no such pipeline preset; available: {names} (a pipeline file is "
                            "named by a path with its suffix, e.g. ./mine.toml)")


def _merge(a: dict, b: dict) -> dict:
    """``b`` layered over ``a``, table by table."""
    out = dict(a)
    for k, v in b.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _read_toml(p: Path) -> dict:
    """A TOML file's tables; ``InputError`` naming the file when it is not valid TOML (or not UTF-8)."""
    try:
        return tomllib.loads(p.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"not valid TOML ({e})", p) from None


def load_pipeline(name_or_path: str | Path | None = None) -> PipelineConfig:
    """A shipped preset by name (``"hough"``: ``pipelines/hough.toml`` inside the package, never a file of the
    current folder) or a TOML file by path (``"./hough.toml"``, anything with a suffix or a slash); ``None`` gives
    the defaults. Parts joined by ``+`` are layered left to right, field by field: ``"crowded+hough"`` is the
    crowded preset with the Hough preset's grouping."""
    if name_or_path is None:
        return PipelineConfig()
    whole_file = _is_path(name_or_path) and Path(name_or_path).is_file()  # a file whose name holds a '+'
    parts = [name_or_path] if whole_file else str(name_or_path).split("+")
    data: dict = {}
    for part in parts:
        p = _preset_path(part)
        layer = _read_toml(p)
        PipelineConfig.from_dict(layer, source=str(p))  # each layer must be valid on its own
        data = _merge(data, layer)
    return PipelineConfig.from_dict(data, source=str(name_or_path))


def field_docs(cls=PipelineConfig, prefix: str = "") -> dict[str, str]:
    """``{"section.field": doc}`` for every field, sub-tables included."""
    out = {}
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        name = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(hints[f.name]):
            out.update(field_docs(hints[f.name], name + "."))
        else:
            out[name] = f.metadata.get("doc", "")
    return out


def dump_toml(cfg: PipelineConfig, comments: bool = True) -> str:
    """The config as TOML text (sections in pipeline order, sub-tables after their section's own fields), each
    parameter with its one-line comment."""
    docs = field_docs() if comments else {}
    lines: list[str] = []

    def section(obj, path: str):
        subs = []
        for f in dataclasses.fields(obj):
            v = getattr(obj, f.name)
            name = f"{path}.{f.name}" if path else f.name
            if dataclasses.is_dataclass(v):
                subs.append((v, name))
                continue
            doc = docs.get(name)
            lines.append(f"{f.name} = {toml_value(v)}" + (f"  # {doc}" if doc else ""))
        for v, name in subs:
            lines.extend(["", f"[{name}]"])
            section(v, name)

    section(cfg, "")
    return "\n".join(lines) + "\n"


def toml_value(v) -> str:
    """A Python value (bool, str, number, list) as TOML writes it."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    return repr(v)


def load_odometry_config(path: str | Path) -> OdometryConfig:
    """``OdometryConfig`` from a TOML file's ``[odometry]`` table (the layout `pcdet odometry` writes as
    ``odometry.toml``, so a run's resolved settings can be given back); fields it leaves out keep their
    defaults. ``InputError`` / ``ConfigError`` name the file on a missing file, bad TOML, an unknown field or a
    bad value."""
    p = Path(path)
    if not p.is_file():
        raise InputError("odometry settings file not found", p)
    data = _read_toml(p)
    unknown = sorted(k for k in data if k != "odometry")
    if unknown or not isinstance(data.get("odometry", {}), dict):
        raise ConfigError(f"expected one [odometry] table, got {unknown or ['odometry = ...']}", str(p))
    return _from_table(OdometryConfig, data.get("odometry", {}), str(p), "odometry")
