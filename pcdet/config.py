"""Pipeline parameters: one frozen dataclass per stage, composed into ``PipelineConfig``, read from TOML.

Lengths are metres. ``pipelines/default.toml`` sets every field to the defaults below (a test checks).
"""
from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass, field
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from .errors import InputError

PIPELINES_DIR = Path(__file__).resolve().parent.parent / "pipelines"


def _positive(obj, *names):
    for n in names:
        v = getattr(obj, n)
        if not (v > 0):
            raise ValueError(f"{type(obj).__name__}.{n} must be > 0, got {v!r}")


@dataclass(frozen=True)
class PreprocessConfig:
    min_depth: float = 0.1
    max_depth: float = 2.5
    voxel: float = 0.004
    normal_radius: float = 0.01
    normal_max_nn: int = 30
    remove_plane: bool = True
    plane_distance: float = 0.008
    plane_iterations: int = 300
    cluster_tolerance: float = 0.012
    min_cluster_points: int = 40

    def __post_init__(self):
        _positive(self, "voxel", "normal_radius", "normal_max_nn", "plane_distance", "cluster_tolerance")
        if not 0 <= self.min_depth < self.max_depth:
            raise ValueError(f"need 0 <= min_depth < max_depth, got {self.min_depth}, {self.max_depth}")


@dataclass(frozen=True)
class KeypointConfig:
    method: str = "voxel"
    spacing: float = 0.008
    iss_salient_radius: float = 0.012
    iss_non_max_radius: float = 0.008

    def __post_init__(self):
        if self.method not in ("voxel", "iss"):
            raise ValueError(f"KeypointConfig.method must be 'voxel' or 'iss', got {self.method!r}")
        _positive(self, "spacing", "iss_salient_radius", "iss_non_max_radius")


@dataclass(frozen=True)
class ModelConfig:
    """How model descriptors are made: from ``views`` rendered partial views at ``view_distance`` m."""

    views: int = 30
    view_distance: float = 0.7

    def __post_init__(self):
        _positive(self, "views", "view_distance")


@dataclass(frozen=True)
class FeatureConfig:
    radius: float = 0.025
    max_nn: int = 100
    lrf_radius: float = 0.0

    def __post_init__(self):
        _positive(self, "radius", "max_nn")
        if self.lrf_radius < 0:
            raise ValueError(f"FeatureConfig.lrf_radius must be >= 0, got {self.lrf_radius}")

    @property
    def lrf_support(self) -> float:
        """m; the radius local reference frames use: ``lrf_radius``, or ``radius`` when that is 0."""
        return self.lrf_radius or self.radius


@dataclass(frozen=True)
class MatchingConfig:
    k: int = 4
    ratio: float = 1.0
    mutual: bool = False

    def __post_init__(self):
        _positive(self, "k")
        if not 0 < self.ratio <= 1:
            raise ValueError(f"MatchingConfig.ratio must be in (0, 1] (1 disables the test), got {self.ratio}")


@dataclass(frozen=True)
class GroupingConfig:
    method: str = "ransac"
    iterations: int = 800
    inlier_distance: float = 0.01
    edge_tolerance: float = 0.006
    normal_tolerance_deg: float = 20.0
    min_inliers: int = 5
    max_instances: int = 2
    alternatives: int = 2
    rescore: int = 20
    min_normal_spread_deg: float = 15.0
    hough_bin: float = 0.015
    hough_min_votes: float = 4.0
    hough_rotation_tol_deg: float = 20.0
    grid_per_diameter: float = 12.0

    def __post_init__(self):
        if self.method not in ("ransac", "gc", "hough"):
            raise ValueError(f"GroupingConfig.method {self.method!r} is not available; choose 'ransac', 'gc' "
                             "or 'hough'")
        _positive(self, "iterations", "inlier_distance", "edge_tolerance", "normal_tolerance_deg",
                  "min_inliers", "max_instances", "grid_per_diameter", "rescore")
        if self.alternatives < 0:
            raise ValueError(f"GroupingConfig.alternatives must be >= 0, got {self.alternatives}")


@dataclass(frozen=True)
class RefineConfig:
    iterations: int = 30
    max_distance: float = 0.012
    kernel: float = 0.006
    max_per_model: int = 3

    def __post_init__(self):
        _positive(self, "iterations", "max_distance", "kernel", "max_per_model")


@dataclass(frozen=True)
class VerifyConfig:
    depth_tolerance: float = 0.008
    min_score: float = 0.35
    min_supported: int = 40
    max_violation: float = 0.25
    conflict_overlap: float = 0.3
    prefilter: float = 0.15
    max_penetration: float = 0.05
    selection: str = "global"
    explain_radius: float = 0.006
    clutter_radius: float = 0.015
    duplicate_weight: float = 1.0
    clutter_weight: float = 5.0
    violation_weight: float = 1.0

    def __post_init__(self):
        _positive(self, "depth_tolerance", "min_supported", "explain_radius", "clutter_radius")
        for n in ("min_score", "max_violation", "conflict_overlap", "prefilter", "max_penetration"):
            if not 0 <= getattr(self, n) <= 1:
                raise ValueError(f"VerifyConfig.{n} must be in [0, 1], got {getattr(self, n)}")
        if self.selection not in ("threshold", "global"):
            raise ValueError(f"VerifyConfig.selection must be 'threshold' or 'global', got {self.selection!r}")
        for n in ("duplicate_weight", "clutter_weight", "violation_weight"):
            if getattr(self, n) < 0:
                raise ValueError(f"VerifyConfig.{n} must be >= 0, got {getattr(self, n)}")


@dataclass(frozen=True)
class PipelineConfig:
    """Every parameter of the detector; ``seed`` drives every random step."""

    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    keypoints: KeypointConfig = field(default_factory=KeypointConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    matching: MatchingConfig = field(default_factory=MatchingConfig)
    grouping: GroupingConfig = field(default_factory=GroupingConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)
    verify: VerifyConfig = field(default_factory=VerifyConfig)
    seed: int = 0

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def replace(self, **sections) -> "PipelineConfig":
        """Copy with some fields changed: ``cfg.replace(seed=3, grouping={"iterations": 500})``."""
        new = {}
        for k, v in sections.items():
            cur = getattr(self, k)
            new[k] = dataclasses.replace(cur, **v) if isinstance(v, dict) else v
        return dataclasses.replace(self, **new)

    @classmethod
    def from_dict(cls, data: dict, source: str | None = None) -> "PipelineConfig":
        kwargs = {}
        sections = {f.name: f for f in dataclasses.fields(cls)}
        for key, value in data.items():
            if key not in sections:
                raise InputError(f"unknown pipeline section {key!r}; known: {sorted(sections)}", source)
            if key == "seed":
                kwargs[key] = int(value)
                continue
            sec_cls = type(getattr(cls(), key))
            known = {f.name for f in dataclasses.fields(sec_cls)}
            if not isinstance(value, dict):
                raise InputError(f"[{key}] must be a table", source)
            bad = set(value) - known
            if bad:
                raise InputError(f"unknown field(s) {sorted(bad)} in [{key}]; known: {sorted(known)}", source)
            try:
                kwargs[key] = sec_cls(**value)
            except (TypeError, ValueError) as e:
                raise InputError(f"[{key}]: {e}", source) from None
        return cls(**kwargs)


def _preset_path(name_or_path: str | Path) -> Path:
    p = Path(name_or_path)
    if not p.suffix and not p.exists():
        p = PIPELINES_DIR / f"{name_or_path}.toml"
        if not p.is_file():
            names = sorted(q.stem for q in PIPELINES_DIR.glob("*.toml"))
            raise FileNotFoundError(f"{name_or_path}: no such pipeline preset; available: {names}")
    if not p.is_file():
        raise FileNotFoundError(f"{p}: pipeline file not found")
    return p


def load_pipeline(name_or_path: str | Path | None = None) -> PipelineConfig:
    """A preset by name (``pipelines/<name>.toml``) or a TOML file path; ``None`` gives the defaults. Presets
    joined by ``+`` are layered left to right, field by field: ``"crowded+hough"`` is the crowded preset with
    the Hough preset's grouping."""
    if name_or_path is None:
        return PipelineConfig()
    parts = [name_or_path] if isinstance(name_or_path, Path) or Path(name_or_path).exists() \
        else str(name_or_path).split("+")
    data: dict = {}
    for part in parts:
        p = _preset_path(part)
        try:
            layer = tomllib.loads(p.read_text())
        except tomllib.TOMLDecodeError as e:
            raise InputError(f"not valid TOML ({e})", p) from None
        PipelineConfig.from_dict(layer, source=str(p))  # each layer must be valid on its own
        for key, value in layer.items():
            data[key] = {**data.get(key, {}), **value} if isinstance(value, dict) else value
    return PipelineConfig.from_dict(data, source=str(name_or_path))


FIELD_DOCS = {
    "seed": "seed of every random step (plane RANSAC, grouping); same input + config + seed = same output",
    "preprocess.min_depth": "m; scene points nearer than this are dropped",
    "preprocess.max_depth": "m; scene points farther than this are dropped",
    "preprocess.voxel": "m; voxel grid of the scene and of model samples",
    "preprocess.normal_radius": "m; neighbourhood for normals (scene, model views)",
    "preprocess.normal_max_nn": "most neighbours used for a normal",
    "preprocess.remove_plane": "remove the dominant plane (table, floor) and what lies beyond it",
    "preprocess.plane_distance": "m; points this close to the plane belong to it",
    "preprocess.plane_iterations": "RANSAC draws for the plane",
    "preprocess.cluster_tolerance": "m; points closer than this join one Euclidean cluster",
    "preprocess.min_cluster_points": "clusters with fewer points are dropped as clutter",
    "model.views": "rendered partial views per model for its descriptors",
    "model.view_distance": "m; distance of those virtual cameras from the model",
    "keypoints.method": "'voxel' (one sample per cell of `spacing`) or 'iss'",
    "keypoints.spacing": "m; keypoint spacing for the voxel method",
    "keypoints.iss_salient_radius": "m; ISS salient radius",
    "keypoints.iss_non_max_radius": "m; ISS non-maximum suppression radius",
    "features.radius": "m; FPFH support radius",
    "features.max_nn": "most neighbours in an FPFH",
    "features.lrf_radius": "m; SHOT local reference frame support (Hough grouping); 0: features.radius",
    "matching.k": "candidate model keypoints kept per scene keypoint (nearest in FPFH space)",
    "matching.ratio": "Lowe ratio test on the nearest two (1.0: off, keep k)",
    "matching.mutual": "keep only mutual nearest neighbours",
    "grouping.method": "correspondence grouping: 'ransac', 'gc' (geometric consistency) or 'hough' (6-DoF voting)",
    "grouping.hough_bin": "m; Hough accumulator cell size",
    "grouping.hough_min_votes": "votes a Hough peak needs (trilinear weights)",
    "grouping.hough_rotation_tol_deg": "degrees; a peak's voters must agree on the rotation within this",
    "grouping.iterations": "triplets drawn per cluster and instance round",
    "grouping.inlier_distance": "m; a correspondence within this of the posed model point is an inlier",
    "grouping.edge_tolerance": "m; pair-length difference allowed between scene and model pairs",
    "grouping.normal_tolerance_deg": "degrees; pair-angle difference allowed (point-pair features)",
    "grouping.min_inliers": "distinct scene keypoints a hypothesis needs",
    "grouping.max_instances": "instances of one model searched per cluster",
    "grouping.alternatives": "extra distinct poses kept per round for verification to choose from",
    "grouping.min_normal_spread_deg": "a triplet needs a normal this far from the others (0: off)",
    "grouping.rescore": "best triplet poses refit and re-ranked by geometric overlap with the scene",
    "grouping.grid_per_diameter": "scene keypoints used for grouping are at least diameter / this apart",
    "refine.iterations": "ICP iterations at most",
    "refine.max_distance": "m; ICP correspondence distance",
    "refine.kernel": "m; Tukey kernel width of the point-to-plane residual",
    "refine.max_per_model": "raw hypotheses per model refined by ICP (best first look first)",
    "verify.depth_tolerance": "m; rendered vs measured depth agreement",
    "verify.min_score": "acceptance threshold on the verification score",
    "verify.min_supported": "pixels that must agree with the model",
    "verify.max_violation": "share of see-through pixels allowed",
    "verify.conflict_overlap": "share of a detection's pixels that may be claimed by a better one",
    "verify.prefilter": "score a raw hypothesis needs before ICP",
    "verify.max_penetration": "share of model samples allowed below the supporting plane",
    "verify.selection": "threshold: all accepted, greedy conflicts; global: the accepted subset that best "
                        "explains the scene",
    "verify.explain_radius": "m; global: a scene point within this of a model sample is explained by it",
    "verify.clutter_radius": "m; global: unexplained scene points this close to explained ones are clutter",
    "verify.duplicate_weight": "global: cost of each scene point explained twice",
    "verify.clutter_weight": "global: cost of each clutter point no chosen detection explains",
    "verify.violation_weight": "global: cost of see-through evidence (in scene points)",
}


def dump_toml(cfg: PipelineConfig, comments: bool = True) -> str:
    """The config as TOML text (sections in pipeline order), each parameter with a one-line comment."""

    def line(key, value, doc_key):
        doc = FIELD_DOCS.get(doc_key) if comments else None
        return f"{key} = {_toml_value(value)}" + (f"  # {doc}" if doc else "")

    lines = [line("seed", cfg.seed, "seed"), ""]
    for f in dataclasses.fields(cfg):
        if f.name == "seed":
            continue
        lines.append(f"[{f.name}]")
        for k, v in dataclasses.asdict(getattr(cfg, f.name)).items():
            lines.append(line(k, v, f"{f.name}.{k}"))
        lines.append("")
    return "\n".join(lines)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    return repr(v)
