"""Synthetic table-top scenes with exact ground truth, written as a BOP dataset.

Each scene: K library objects resting on a table (a stable pose of each, a random yaw, no two footprints
overlapping), a VGA camera with Kinect-like intrinsics on a hemisphere looking at them, depth rendered with
open3d's RaycastingScene and degraded by a sensor model (``pcdet.sensor``; by default a structured-light
Kinect: Nguyen et al. 2012 axial noise sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2 m, correlated between
neighbouring pixels, depth in steps of a disparity quantised to 1/8 pixel, dropped pixels at depth edges).
"""
from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .align import transform
from .camera import Camera
from .errors import ConfigError, InputError
from .io.atomic import atomic_write_text
from .io.bop import camera_pose_to_bop, camera_to_bop, pose_to_bop
from .io.depth import write_depth_png, write_png
from .library import ModelLibrary
from .render import render_meshes
from .sensor import SENSORS, apply_sensor

KINECT = Camera(572.4114, 573.57043, 325.2611, 242.04899, 640, 480, 1.0)
TABLE_HALF = 0.5  # m
TABLE_THICKNESS = 0.02


@dataclass(frozen=True)
class SynthConfig:
    """scenes: number of scenes (one image each); objects: library objects per scene (distinct);
    instances: copies of one object allowed per scene (up to this many); distractors: clutter objects that are
    not in the library (random boxes, cylinders, cones, spheres and capsules, 3-12 cm; no ground truth);
    distance and elevation of the camera (m, degrees); area: radius (m) of the table disc the objects stand in;
    noise: apply the sensor model; sensor: which (``pcdet.sensor.SENSORS``: "structured_light_band", the
    default, structured-light noise with a real Kinect's object edges; "structured_light", the same noise with
    edge pixels dropped instead, the default until 2026-12; or "independent", per-pixel noise, pcdet's model until
    2026-11; the scenes are the same for every model);
    sequence: frames per scene (0: one image) taken by a camera that moves smoothly around the table, sweeping
    ``sweep_deg`` of azimuth while its elevation and distance waver; mesh_error (m RMS) and mesh_error_length (m):
    each library object is rendered from a copy of its mesh whose surface is moved along its normals by a smooth
    random field of that size and correlation length (``perturbed_mesh``), while ``models/`` keeps the meshes as
    given, so the objects differ from their models as a real object differs from its scan (0: the meshes as
    they are; the scenes' poses are the same either way). The defaults (``structured_light_band``, 1.2 mm) are
    what made twins of real LINEMOD frames match as the real frames do (``scripts/sim_to_real.py``); the
    idealised suites of before are ``sensor="structured_light", mesh_error=0``."""

    scenes: int = 20
    objects: int = 4
    instances: int = 1
    distractors: int = 0
    distance: tuple[float, float] = (0.6, 0.9)
    elevation_deg: tuple[float, float] = (35.0, 70.0)
    area: float = 0.2
    noise: bool = True
    sensor: str = "structured_light_band"
    seed: int = 0
    sequence: int = 0
    sweep_deg: float = 90.0
    # m RMS; from scripts/sim_to_real.py: the real cat lies 2.16 mm RMS from its mesh, its twins 1.78-1.86 mm
    # (their sensor noise); about 1.2 mm more, added independently, gave twins the real residual
    mesh_error: float = 0.0012
    # m; from a trial on the LINEMOD cat's twins (``scripts/sim_to_real.py``): a 1.2 mm field laid on their depth,
    # white noise blurred by 6 px (a correlation of 13 mm at 0.87 m), gave them the real frames' surface residual
    mesh_error_length: float = 0.013

    def __post_init__(self):
        for name, low in (("scenes", 1), ("objects", 1), ("instances", 1), ("distractors", 0), ("sequence", 0)):
            if getattr(self, name) < low:
                raise ConfigError(f"synth {name} must be >= {low}, got {getattr(self, name)}")
        if self.sensor not in SENSORS:
            raise ConfigError(f"synth sensor must be one of {', '.join(SENSORS)}, got {self.sensor!r}")
        if self.mesh_error < 0 or self.mesh_error_length <= 0:
            raise ConfigError(f"synth mesh_error must be >= 0 and mesh_error_length > 0, got {self.mesh_error} and "
                              f"{self.mesh_error_length}")


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """T_world_cam for a camera at ``eye`` looking at ``target`` with the world z axis up in the image."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.array([0.0, 0.0, 1.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T


def _rot_z(a: float) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(a), np.sin(a)
    T[:2, :2] = [[c, -s], [s, c]]
    return T


class _Placer:
    """Stable resting poses per model, computed once (trimesh's quasi-static analysis)."""

    def __init__(self, meshes):
        self.meshes = meshes
        self.poses = {}

    def stable(self, i):
        if i not in self.poses:
            import trimesh

            v = np.asarray(self.meshes[i][0], float)
            sv = np.linalg.svd(v - v.mean(axis=0), compute_uv=False) if len(v) >= 3 else np.zeros(3)
            T = []
            # a model with no volume (flat, or one triangle) has no stable pose to compute: qhull cannot hull it,
            # and trimesh's analysis of a zero-thickness box never ends
            if sv[2] > 1e-6 * sv[0]:
                T, p = trimesh.Trimesh(*self.meshes[i], process=True).compute_stable_poses(n_samples=1,
                                                                                           threshold=0.02)
            if len(T) == 0:
                T, p = _lying_flat(v)[None], np.ones(1)
            self.poses[i] = (np.asarray(T), np.asarray(p) / np.sum(p))
        return self.poses[i]


def _lying_flat(vertices: np.ndarray) -> np.ndarray:
    """(4, 4) rotation that turns the direction in which ``vertices`` (N, 3) are thinnest (their least principal
    axis) to +z, so that a model with no stable pose to compute (a flat one) lies on its face."""
    c = vertices - vertices.mean(axis=0)
    R = np.linalg.svd(c)[2] if len(c) >= 3 else np.eye(3)  # rows: most to least spread; the last becomes z
    if np.linalg.det(R) < 0:
        R[1] = -R[1]
    T = np.eye(4)
    T[:3, :3] = R
    return T


def _table_mesh():
    import trimesh

    t = trimesh.creation.box((2 * TABLE_HALF, 2 * TABLE_HALF, TABLE_THICKNESS))
    t.apply_translation((0, 0, -TABLE_THICKNESS / 2))
    return np.asarray(t.vertices), np.asarray(t.faces)


def distractor_mesh(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random clutter shape (vertices (V, 3) m, faces (F, 3)): box, cylinder, cone, sphere or capsule with
    dimensions between 3 and 12 cm."""
    import trimesh

    kind = int(rng.integers(5))
    u = lambda lo, hi: float(rng.uniform(lo, hi))  # noqa: E731
    if kind == 0:
        m = trimesh.creation.box((u(0.03, 0.12), u(0.03, 0.12), u(0.03, 0.12)))
    elif kind == 1:
        m = trimesh.creation.cylinder(radius=u(0.015, 0.05), height=u(0.03, 0.12), sections=48)
    elif kind == 2:
        m = trimesh.creation.cone(radius=u(0.02, 0.05), height=u(0.04, 0.12), sections=48)
    elif kind == 3:
        m = trimesh.creation.icosphere(subdivisions=3, radius=u(0.015, 0.045))
    else:
        m = trimesh.creation.capsule(height=u(0.03, 0.08), radius=u(0.015, 0.03), count=[24, 24])
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def _place(verts: np.ndarray, T_st: np.ndarray, prob: np.ndarray, cfg: SynthConfig, rng: np.random.Generator,
           circles: list) -> np.ndarray | None:
    """A resting pose (one of the stable ones, random yaw and position) whose footprint circle overlaps none in
    ``circles`` (which it joins), or None after 200 tries."""
    for _ in range(200):
        k = rng.choice(len(T_st), p=prob)
        T = _rot_z(rng.uniform(0, 2 * np.pi)) @ T_st[k]
        v = transform(T, verts)
        T[2, 3] -= v[:, 2].min()  # rest on the table top
        c = (v[:, :2].max(0) + v[:, :2].min(0)) / 2
        r = float(np.linalg.norm(v[:, :2] - c, axis=1).max())
        r_pos = rng.uniform(0, cfg.area) ** 0.5 * cfg.area ** 0.5
        ang = rng.uniform(0, 2 * np.pi)
        shift = np.array([r_pos * np.cos(ang), r_pos * np.sin(ang)]) - c
        centre = c + shift
        if all(np.linalg.norm(centre - c2) > r + r2 + 0.003 for c2, r2 in circles):
            T[:2, 3] += shift
            circles.append((centre, r))
            return T
    return None


def compose_scene(lib: ModelLibrary, cfg: SynthConfig, rng: np.random.Generator, placer: _Placer):
    """Pick objects and poses on the table: ``(placed, clutter)``, ``placed`` a list of ``(model index,
    T_world_model)``, ``clutter`` a list of ``(vertices, faces, T_world_mesh)`` of distractors."""
    n_obj = min(cfg.objects, len(lib))
    chosen = rng.choice(len(lib), size=n_obj, replace=False)
    items = []
    for i in chosen:
        copies = int(rng.integers(1, cfg.instances + 1)) if cfg.instances > 1 else 1
        items += [int(i)] * copies
    placed, circles, clutter = [], [], []
    for i in items:
        T = _place(lib[i].vertices, *placer.stable(i), cfg, rng, circles)
        if T is not None:
            placed.append((i, T))
    for _ in range(cfg.distractors):
        v, f = distractor_mesh(rng)
        T = _place(v, *_Placer({0: (v, f)}).stable(0), cfg, rng, circles)
        if T is not None:
            clutter.append((v, f, T))
    return placed, clutter


def perturbed_mesh(vertices: np.ndarray, faces: np.ndarray, rms: float, length: float, rng: np.random.Generator
                   ) -> tuple[np.ndarray, np.ndarray]:
    """A copy of the mesh (vertices (V, 3) m, faces (F, 3)) with its surface moved along the vertex normals by a
    smooth random field: RMS ``rms`` m over the vertices, its correlation a Gaussian of standard deviation
    ``length`` m (64 random Fourier features of that kernel). The mesh is first subdivided to edges of at most
    ``length`` / 2, so that a coarse mesh (a box of 12 triangles) can bend too. Returns (vertices, faces)."""
    import trimesh

    v, f = trimesh.remesh.subdivide_to_size(np.asarray(vertices, float), np.asarray(faces), max_edge=length / 2,
                                            max_iter=20)
    mesh = trimesh.Trimesh(v, f, process=True)  # duplicate vertices (texture seams) merged: no cracks open
    v, f, normals = np.asarray(mesh.vertices), np.asarray(mesh.faces), np.asarray(mesh.vertex_normals)
    w = rng.normal(size=(64, 3)) / length
    phase = rng.uniform(0, 2 * np.pi, 64)
    field = np.cos(v @ w.T + phase).sum(axis=1)
    field /= max(float(np.sqrt(np.mean(field ** 2))), 1e-12)
    return v + (rms * field)[:, None] * normals, f


def render_scene(lib, placed, T_world_cam, camera, rng, *, clutter=(), sensor="structured_light_band",
                 shapes=None):
    """Render one view of the library objects ``placed`` and the distractors ``clutter`` (see
    ``compose_scene``) through the sensor model ``sensor`` (``pcdet.sensor.SENSORS``; "none": depth rounded to
    1 mm): returns (raw depth uint16 mm, rgb uint8, gt list, gt_info list); ground truth covers ``placed`` only.
    ``shapes``: {library index: (vertices, faces)} rendered instead of the library's own mesh (``perturbed_mesh``)."""
    T_cam_world = np.linalg.inv(T_world_cam)
    tv, tf = _table_mesh()
    shapes = shapes or {}
    shape = {i: shapes.get(i, (lib[i].vertices, lib[i].faces)) for i, _ in placed}
    meshes = [(tv, tf, T_cam_world)] + [(*shape[i], T_cam_world @ T) for i, T in placed]
    meshes += [(v, f, T_cam_world @ T) for v, f, T in clutter]
    r = render_meshes(camera, meshes)
    raw = apply_sensor(sensor, r.depth, rng, camera.fx)
    # shaded colour image: Lambert from a light at the camera, one hue per object, grey table and clutter
    shade = np.clip(-r.normals[..., 2], 0.15, 1.0)[..., None]
    palette = np.array([[200, 200, 200]] + [_colour(lib[i].obj_id) for i, _ in placed]
                       + [[120, 120, 120]] * len(clutter), float)
    rgb = np.where(r.ids[..., None] >= 0, palette[np.maximum(r.ids, 0)] * shade, 30).astype(np.uint8)
    gt, info = [], []
    for k, (i, T) in enumerate(placed, start=1):
        T_cm = T_cam_world @ T
        alone = render_meshes(camera, [(*shape[i], T_cm)])
        all_px = alone.ids >= 0
        vis_px = (r.ids == k) & (raw > 0)
        n_all, n_vis = int(all_px.sum()), int(vis_px.sum())
        gt.append({**pose_to_bop(T_cm), "obj_id": int(lib[i].obj_id)})
        info.append({"bbox_obj": _bbox(all_px), "bbox_visib": _bbox(vis_px), "px_count_all": n_all,
                     "px_count_valid": n_vis, "px_count_visib": n_vis,
                     "visib_fract": round(n_vis / n_all, 6) if n_all else 0.0})
    return raw, rgb, gt, info


def _colour(obj_id: int) -> list[float]:
    h = (obj_id * 0.61803398875) % 1.0
    import colorsys

    return [255 * c for c in colorsys.hsv_to_rgb(h, 0.55, 0.95)]


def _bbox(mask: np.ndarray) -> list[int]:
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)]


def write_models(lib: ModelLibrary, out: Path) -> None:
    """The library's meshes in millimetres with a BOP models_info.json."""
    import trimesh

    out.mkdir(parents=True, exist_ok=True)
    info = {}
    for m in lib:
        v = m.vertices * 1000.0
        trimesh.Trimesh(v, m.faces, process=False).export(out / f"obj_{m.obj_id:06d}.ply", encoding="binary")
        lo, hi = v.min(0), v.max(0)
        info[str(m.obj_id)] = {"name": m.name, "diameter": m.diameter * 1000.0, "min_x": lo[0], "min_y": lo[1],
                               "min_z": lo[2], "size_x": hi[0] - lo[0], "size_y": hi[1] - lo[1],
                               "size_z": hi[2] - lo[2]}
    atomic_write_text(out / "models_info.json", json.dumps(info, indent=1, default=float))


def camera_path(az: float, el: float, dist: float, target: np.ndarray, cfg: SynthConfig) -> list[np.ndarray]:
    """``T_world_cam`` of each frame: one view for ``cfg.sequence`` 0, else ``cfg.sequence`` views sweeping
    ``cfg.sweep_deg`` of azimuth from ``az`` with elevation (+-4 deg) and distance (+-3 cm) wavering."""
    n = max(cfg.sequence, 1)
    out = []
    for k in range(n):
        u = k / max(n - 1, 1) if cfg.sequence else 0.0
        a = az + np.radians(cfg.sweep_deg) * u
        e = el + np.radians(4.0) * np.sin(2 * np.pi * u) if cfg.sequence else el
        d = dist + 0.03 * np.sin(np.pi * u) if cfg.sequence else dist
        eye = d * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        out.append(_look_at(eye, target))
    return out


def check_synth_folder(out: Path, *, overwrite: bool = False) -> None:
    """Refuse an ``out`` that already holds synthetic scenes (``out/test/<scene>``), unless ``overwrite``:
    scenes of another seed or size must not be left beside the new ones."""
    old = [d for d in (out / "test").iterdir() if d.is_dir()] if (out / "test").is_dir() else []
    if old and not overwrite:
        raise InputError(f"already holds {len(old)} scene(s) in test/: pass --overwrite (overwrite=True) to "
                         "replace them, or choose another folder", out)


def synthesize(lib: ModelLibrary, out, cfg: SynthConfig, camera: Camera = KINECT, *, overwrite: bool = False,
               progress: Callable[[int, int], None] | None = None) -> Path:
    """Write ``cfg.scenes`` scenes as ``out/test/<scene>/`` (one image each) plus ``out/models`` and
    ``out/camera.json``. Returns ``out``. A folder that holds scenes already is refused, or with ``overwrite``
    its ``test/`` and ``models/`` are removed first."""
    out = Path(out)
    check_synth_folder(out, overwrite=overwrite)
    if overwrite:
        for sub in ("test", "models"):
            if (out / sub).is_dir():
                shutil.rmtree(out / sub)
    no_mesh = [m.name for m in lib if not m.is_mesh]
    if no_mesh:
        raise InputError(f"synth renders meshes; these models are point clouds: {no_mesh}")
    rng = np.random.default_rng(cfg.seed)
    sensor_rng = np.random.default_rng([cfg.seed, 1])  # its own stream: the scenes do not depend on the sensor model
    placer = _Placer({i: (m.vertices, m.faces) for i, m in enumerate(lib)})
    shapes = None
    if cfg.mesh_error > 0:  # its own stream too: the scenes and the sensor's draws do not depend on it
        mesh_rng = np.random.default_rng([cfg.seed, 2])
        shapes = {i: perturbed_mesh(m.vertices, m.faces, cfg.mesh_error, cfg.mesh_error_length, mesh_rng)
                  for i, m in enumerate(lib)}
    write_models(lib, out / "models")
    atomic_write_text(out / "camera.json", json.dumps({"cx": camera.cx, "cy": camera.cy, "fx": camera.fx,
                                                        "fy": camera.fy, "width": camera.width,
                                                        "height": camera.height, "depth_scale": 1.0}, indent=1))
    for s in range(1, cfg.scenes + 1):
        placed, clutter = compose_scene(lib, cfg, rng, placer)
        az = rng.uniform(0, 2 * np.pi)
        el = np.radians(rng.uniform(*cfg.elevation_deg))
        dist = rng.uniform(*cfg.distance)
        target = np.array([*rng.normal(0, 0.02, 2), 0.03])
        sdir = out / "test" / f"{s:06d}"
        cams, gts, infos = {}, {}, {}
        for k, T_world_cam in enumerate(camera_path(az, el, dist, target, cfg)):
            raw, rgb, gt, info = render_scene(lib, placed, T_world_cam, camera, sensor_rng, clutter=clutter,
                                              sensor=cfg.sensor if cfg.noise else "none", shapes=shapes)
            write_depth_png(sdir / "depth" / f"{k:06d}.png", raw)
            write_png(sdir / "rgb" / f"{k:06d}.png", rgb)
            cams[str(k)] = {**camera_to_bop(camera.K, 1.0), **camera_pose_to_bop(T_world_cam)}
            gts[str(k)], infos[str(k)] = gt, info
        atomic_write_text(sdir / "scene_camera.json", json.dumps(cams, indent=1))
        atomic_write_text(sdir / "scene_gt.json", json.dumps(gts, indent=1))
        atomic_write_text(sdir / "scene_gt_info.json", json.dumps(infos, indent=1))
        if progress:
            progress(s, cfg.scenes)
    return out
