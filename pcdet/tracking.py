"""Object tracking through an RGB-D recording, in a world-frame map of static object instances.

The world frame is the first camera's. Frame by frame:
  1. camera odometry (``odometry.Odometry``) predicts ``T_world_cam``;
  2. on the first frame, every ``redetect_every`` frames, (``confirm``) on the frame after a map pose was set, so
     that no map pose rests on one detection alone, and in a frame where tracking (3) fails, a track lost or every
     instance seen in the frame before predicted out of view (the camera moved further than odometry followed),
     that same frame: full detection. The camera is first relocalised on the mapped objects where they put it
     better than odometry did (``Tracker._relocalised``); then each detection joins the track of the same object
     whose map position is within ``associate_distance`` x the model's diameter, or starts a new track; a
     detection that joins a track competes with the track's own prediction refined as in 3, and the better
     verified pose is kept. A detection that wins and puts the model elsewhere than the refined prediction (model
     samples a mean of ``reanchor_distance`` x the diameter apart), or where the prediction could not be verified
     at all, replaces the track's map pose: the map was wrong (a first detection of a near-symmetric part turned
     the wrong way round, which ICP from the map pose keeps finding again);
  3. otherwise each mapped instance in view is refined by ICP from its predicted pose (map pose seen from the
     predicted camera), on the depth pixels around it only, and checked against the depth (``verify``); a score
     below ``min_score`` marks it lost, and the frame goes to full detection (2);
  4. the instances seen in this frame correct the camera pose: the rigid fit of their model points as observed
     onto the same points in the map (objects do not move, so any disagreement is camera drift). Instances whose
     map pose is set in this frame (new tracks, replaced map poses) take no part in it; they are mapped from the
     corrected pose. The corrected pose goes back to the odometry;
  5. each instance seen reports the mean of its world poses observed (corrected camera pose x observed object
     pose) since its map pose was set, seen from the corrected camera: the object does not move, so the mean of
     its views is a better estimate of where it is than any one of them (one ICP that slid along a near-symmetric
     part moves it by a fraction). The map pose itself stays as set: predictions start from it.
Every track keeps its per-frame world pose estimate (the observed pose of step 5).

``track_into`` writes what detection writes (a detections JSON per frame as it is done, ``results.csv`` rebuilt
from them) plus ``tracks.json``, and checkpoints the tracker after every frame, so that a killed run resumes
where it stopped and gives the same ``results.csv``.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from .align import kabsch, transform
from .detector import Detection, DetectionResult, Detector
from .frame import Frame
from .errors import ConfigError, InputError
from .io.atomic import atomic_write_bytes, atomic_write_text
from .metrics import add, adds
from .odometry import Odometry, OdometryConfig
from .odometry_run import relocalise
from .params import check_positive


@dataclass(frozen=True)
class TrackingConfig:
    """redetect_every: full detection every N frames besides the first and where tracking fails (0: only then);
    min_score: verification score a tracked pose must keep; associate_distance: x model diameter;
    reanchor_distance: x model diameter, mean distance of the model samples between a better-verified detection and
    the track's refined prediction above which the detection replaces the track's map pose (step 2 of the module
    docstring); confirm: a full detection on the frame after a map pose was set (a new track, a replaced map pose),
    which replaces a first detection turned the wrong way round there instead of at the next ``redetect_every``
    (one more full detection for each frame that sets map poses); crop_margin: m of depth around a predicted object
    used for its ICP; odometry: camera odometry settings.
    The default odometry is frame-to-frame ICP on a coarse grid (2 cm at 1 m), without KISS-ICP: the objects
    correct the camera every frame, so odometry only has to bring each object within ICP's reach. On a 60-frame
    recording, run back to back (``python scripts/bench_tracking.py``, then the same with
    ``OdometryConfig()``), the largest object error was 2.30 mm with it and 2.28 mm with the finer default
    odometry, at 13.5 against 6.0 tracking frames per second. That was before the odometry weighed points by
    their depth noise and before the sensor model's random stream changed the scenes; today the benchmark gives
    2.71 mm at 13.2 frames per second, 2.52 mm since new and replaced map poses are mapped from the corrected
    camera (docs/measurements.md, "A wrong map pose replaced"), and 2.38 mm with the compiled normals, with
    ``confirm`` or without (it adds full detections in frames 1 and 16: 6 instead of 4). Its ICP kernel stays two
    grid spacings wide (``icp_kernel``; the recording odometry's default is one): with one, a T-joint of
    ``tests/test_tracking.py``'s recording strayed 9.4 mm from the truth in one frame.
"""

    redetect_every: int = 15
    min_score: float = 0.5
    associate_distance: float = 0.25
    reanchor_distance: float = 0.05
    confirm: bool = True
    crop_margin: float = 0.03
    odometry: OdometryConfig = field(default_factory=lambda: OdometryConfig(
        method="icp", icp_voxel=0.02, pixel_stride=2, keyframe_distance=0.0, keyframe_angle_deg=0.0, keyframes=1,
        icp_kernel=2.0))

    def __post_init__(self):
        check_positive(self, "associate_distance", "reanchor_distance", "crop_margin")
        if self.redetect_every < 0:
            raise ConfigError(f"TrackingConfig.redetect_every must be >= 0, got {self.redetect_every}")
        if not 0 <= self.min_score <= 1:
            raise ConfigError(f"TrackingConfig.min_score must lie in [0, 1], got {self.min_score}")


@dataclass
class Track:
    """One object instance: its map pose ``T_world_model`` (4, 4, m), which predictions start from and the camera
    is corrected against; ``T_world_fused``, the mean of the ``fused`` world poses observed since the map pose was
    last set from a detection (``observe``), which is what the track reports; and, per frame it was seen in, the
    world pose observed, the verification score and how it was found ("detect" or "track")."""

    id: int
    model: str
    obj_id: int
    model_index: int
    T_world_model: np.ndarray
    fused: int = 0
    pose_sum: np.ndarray | None = None
    frames: list[int] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)
    scores: list[float] = field(default_factory=list)
    modes: list[str] = field(default_factory=list)
    lost: bool = False

    def observe(self, T_world_model: np.ndarray, *, anchor: bool = False) -> None:
        """Add one observed world pose (4, 4) to the views ``T_world_fused`` averages (their sum ``pose_sum``, their
        number ``fused``). With ``anchor`` the observation also sets the map pose, and the mean starts again from
        it."""
        T = np.asarray(T_world_model, float)
        if anchor:
            self.T_world_model = T.copy()
        if anchor or self.fused == 0:
            self.pose_sum, self.fused = T.copy(), 1
        else:
            self.pose_sum, self.fused = self.pose_sum + T, self.fused + 1

    @property
    def T_world_fused(self) -> np.ndarray | None:
        """(4, 4) the mean of the views since the map pose was set: translations averaged, rotations by their
        chordal mean (the rotation nearest the sum of the rotation matrices); a single view as it is; None before
        any."""
        if self.fused <= 1:
            return None if self.pose_sum is None else self.pose_sum.copy()
        U, _, Vt = np.linalg.svd(self.pose_sum[:3, :3])
        M = np.eye(4)
        M[:3, :3] = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
        M[:3, 3] = self.pose_sum[:3, 3] / self.fused
        return M

    def to_dict(self) -> dict:
        """The track as tracks.json stores it (poses rounded to 1e-9)."""
        return {"id": self.id, "model": self.model, "obj_id": self.obj_id,
                "T_world_model": np.round(self.T_world_model, 9).tolist(),
                "T_world_fused": None if self.fused == 0 else np.round(self.T_world_fused, 9).tolist(),
                "observations": [{"frame": f, "T_world_model": np.round(T, 9).tolist(), "score": round(s, 6),
                                  "mode": m} for f, T, s, m in zip(self.frames, self.poses, self.scores,
                                                                   self.modes)]}


@dataclass
class TrackingResult:
    """Per frame: the corrected ``T_world_cam`` (None for a frame that could not be read), the mode ("detect",
    "track" or "failed: <why>"), the seconds it took and the objects seen in it (``Detection`` s, camera
    frame, as ``Detector.detect`` gives them); and the tracks."""

    tracks: list[Track]
    camera_poses: list[np.ndarray | None]
    modes: list[str]
    seconds: list[float]
    detections: list[list[Detection]] = field(default_factory=list)

    def to_dict(self) -> dict:
        """The tracks, camera poses and frame modes as tracks.json stores them."""
        return {"tracks": [t.to_dict() for t in self.tracks],
                "camera_poses": [None if T is None else np.round(T, 9).tolist() for T in self.camera_poses],
                "frame_modes": self.modes}


class Tracker:
    """Follows a recording frame by frame (``step``, ``run``): odometry, full detections when due,
    ``Detector.refine`` between them, camera corrected by the objects (see the module docstring)."""

    def __init__(self, detector: Detector, config: TrackingConfig | None = None):
        self.det = detector
        self.cfg = config or TrackingConfig()
        self.odo = Odometry(self.cfg.odometry, relocalise)  # a frame that fits its map badly: as `pcdet odometry`
        self.tracks: list[Track] = []
        self.index = -1
        self.last_detections: list[Detection] = []
        self._unconfirmed = False  # a map pose was set from one detection in the last frame

    def step(self, frame: Frame) -> tuple[np.ndarray, str]:
        """Process the next frame: returns (corrected T_world_cam, "detect" or "track")."""
        self.index += 1
        T_wc = self.odo.step(frame)
        due = self.cfg.redetect_every > 0 and self.index % self.cfg.redetect_every == 0
        mapped: set[int] = set()  # ids of the tracks whose map pose this frame sets
        mode = "detect"
        if not (self.index == 0 or due or self._unconfirmed):
            seen_last = any(t.frames and t.frames[-1] == self.index - 1 for t in self.tracks)
            obs, in_view = self._track(frame, T_wc)
            mode = "track"
            # tracking failed in this frame: a track lost, or every object seen in the last frame gone from view at
            # once (the camera moved further than odometry followed): detect in this frame, not the next
            if any(t.lost for t in self.tracks) or (seen_last and not in_view):
                mode = "detect"
        if mode == "detect":
            obs, mapped, T_wc = self._detect(frame, T_wc)
        if obs:
            anchored = [o for o in obs if o[0].id not in mapped]
            if anchored:
                T_wc = self._correct_camera(anchored, T_wc)
            self.odo.reset(T_wc)
        T_input_world = frame.T_input_cam @ np.linalg.inv(T_wc)
        self.last_detections = []
        for tr, T_cm, score, d in obs:
            T_wm = T_wc @ T_cm
            tr.observe(T_wm, anchor=tr.id in mapped)
            tr.frames.append(self.index)
            tr.poses.append(T_wm)
            tr.scores.append(score)
            tr.modes.append(mode)
            # the frame's pose of a static object: the mean of its views since its map pose was set, seen from here
            self.last_detections.append(replace(d, T_cam_model=T_input_world @ tr.T_world_fused))
        self._unconfirmed = self.cfg.confirm and bool(mapped)
        return T_wc, mode

    def _detect(self, frame: Frame, T_wc: np.ndarray
                ) -> tuple[list[tuple[Track, np.ndarray, float, Detection]], set[int], np.ndarray]:
        """Full detection (step 2 of the module docstring): the observations (track, T_cam_model, score,
        detection), the ids of the tracks whose map pose is to be set from this frame, and the camera pose
        ``T_wc`` (4, 4), relocalised on the mapped objects where they put it better (``_relocalised``)."""
        res = self.det.detect(frame)
        obs = []
        used: set[int] = set()
        mapped: set[int] = set()
        T_cam_input = np.linalg.inv(frame.T_input_cam)
        seen = [(d, T_cam_input @ d.T_cam_model) for d in res.detections]
        T_wc = self._relocalised(seen, T_wc)
        T_cw = np.linalg.inv(T_wc)
        for d, T_cm in seen:
            mi = self.det.library.index_of(d.obj_id)
            m = self.det.library[mi]
            T_wm = T_wc @ T_cm
            best = self._nearest_track(d.obj_id, T_wm[:3, 3], used)
            if best is None:
                best = Track(len(self.tracks) + 1, m.name, m.obj_id, mi, T_wm)
                self.tracks.append(best)
                mapped.add(best.id)
            else:  # the track's own prediction, refined, competes with the detection: the better verified wins
                r = self.det.refine(frame, mi, T_cw @ best.T_world_model, depth_margin=self.cfg.crop_margin)
                if r.detection is not None and r.detection.score > d.score:
                    d = r.detection
                    T_cm = T_cam_input @ d.T_cam_model
                elif r.detection is None or self._apart(mi, r.detection.T_cam_model, d.T_cam_model):
                    mapped.add(best.id)  # the map pose no longer holds: the detection's replaces it
            used.add(best.id)
            best.lost = False
            obs.append((best, T_cm, float(d.score), d))
        for tr in self.tracks:
            tr.lost = False  # a full detection settles every loss: missing objects simply are not in view
        return obs, mapped, T_wc

    def _nearest_track(self, obj_id: int, p: np.ndarray, taken: set[int] | frozenset = frozenset()) -> Track | None:
        """The track of object ``obj_id`` whose map position lies nearest the world position ``p`` (3,, m), within
        ``associate_distance`` x the model's diameter and not among the ids ``taken``; None where there is none."""
        best, best_d = None, self.cfg.associate_distance * self.det.library[self.det.library.index_of(obj_id)].diameter
        for tr in self.tracks:
            dist = np.linalg.norm(tr.T_world_model[:3, 3] - p)
            if tr.obj_id == obj_id and tr.id not in taken and dist < best_d:
                best, best_d = tr, dist
        return best

    def _near_tracks(self, seen: list[tuple[Detection, np.ndarray]], T_wc: np.ndarray) -> int:
        """How many of the detections ``seen`` ((detection, T_cam_model) pairs) fall on a track from camera ``T_wc``
        (4, 4): they would join it (``_nearest_track``), and their pose lies within ``reanchor_distance`` x the
        model's diameter of its map pose by ADD-S (the mean distance from each model sample to the nearest of the
        other pose's: a symmetric object turned about its symmetry still falls on its track). The position alone
        would not tell: on the real LINEMOD cat recording a camera relocalised 0.9 m and 87 degrees off the truth put
        the cat within 0.10 of its diameter of its track, turned (ADD-S 0.11 of the diameter, against 0.02-0.03
        where the camera was right)."""
        n = 0
        for d, T_cm in seen:
            T_wm = T_wc @ T_cm
            tr = self._nearest_track(d.obj_id, T_wm[:3, 3])
            if tr is not None:
                pm = self.det.models[tr.model_index]
                n += adds(T_wm, tr.T_world_model, pm.icp_points) <= self.cfg.reanchor_distance * pm.model.diameter
        return n

    def _relocalised(self, seen: list[tuple[Detection, np.ndarray]], T_wc: np.ndarray) -> np.ndarray:
        """The camera pose (4, 4) as the mapped objects put it: of the odometry's ``T_wc`` and each pose that lays
        one detection of ``seen`` exactly onto a track of its object (the objects do not move), the one under
        which most detections fall on tracks of their objects (``_near_tracks``); the odometry's unless another
        does better (where odometry followed the camera, every detection of a mapped object already does), the
        first found among equals. Where the camera moved further than odometry followed, the detections would
        otherwise start new tracks beside the old ones, and the map and the camera would stay wrong."""
        best, most = T_wc, self._near_tracks(seen, T_wc)
        if most == len(seen):  # every detection falls on a track already: no camera can do better
            return best
        for d, T_cm in seen:
            for tr in self.tracks:
                if tr.obj_id == d.obj_id:
                    C = tr.T_world_model @ np.linalg.inv(T_cm)
                    n = self._near_tracks(seen, C)
                    if n > most:
                        best, most = C, n
        return best

    def _apart(self, model_index: int, A: np.ndarray, B: np.ndarray) -> bool:
        """Whether poses A and B (4, 4) of a model put its samples a mean of more than ``reanchor_distance`` x
        its diameter apart (their ADD)."""
        pm = self.det.models[model_index]
        return add(A, B, pm.icp_points) > self.cfg.reanchor_distance * pm.model.diameter

    def _track(self, frame: Frame, T_wc: np.ndarray) -> tuple[list[tuple[Track, np.ndarray, float, Detection]], int]:
        """Each mapped instance refined from its prediction (step 3 of the module docstring): the observations
        (track, T_cam_model, score, detection) and how many instances were predicted in view; a track whose
        refined pose fails is marked lost."""
        T_cw = np.linalg.inv(T_wc)
        T_cam_input = np.linalg.inv(frame.T_input_cam)
        obs, in_view = [], 0
        for tr in self.tracks:
            r = self.det.refine(frame, tr.model_index, T_cw @ tr.T_world_model, depth_margin=self.cfg.crop_margin)
            if not r.in_view:
                continue  # nothing to say about it here
            in_view += 1
            if r.detection is None or r.detection.score < self.cfg.min_score:
                tr.lost = True
                continue
            obs.append((tr, T_cam_input @ r.detection.T_cam_model, float(r.detection.score), r.detection))
        return obs, in_view

    def _correct_camera(self, obs, T_wc: np.ndarray) -> np.ndarray:
        """The camera pose that best maps the observed objects onto the map: Kabsch on their model samples."""
        src, dst = [], []
        for tr, T_cm, *_ in obs:
            p = self.det.models[tr.model_index].icp_points
            src.append(transform(T_cm, p))
            dst.append(transform(tr.T_world_model, p))
        src, dst = np.vstack(src), np.vstack(dst)
        if len(obs) == 1:
            # one object fixes the camera fully, but a symmetric one does not: keep the odometry unless it agrees
            T = kabsch(src, dst)
            return T if np.linalg.norm((T @ np.linalg.inv(T_wc))[:3, 3]) < 0.05 else T_wc
        return kabsch(src, dst)

    def run(self, rec, on_frame=None, *, checkpoint=None, result: TrackingResult | None = None
            ) -> TrackingResult:
        """Track through every frame of recording ``rec``; ``on_frame(i, mode, seconds)`` after each. A frame
        that cannot be read is reported in its mode and skipped (the odometry bridges the gap).

        result : a partial result to continue (from ``restore``): its frames are not tracked again.
        checkpoint : ``checkpoint(i, ref, result, tracker)`` after each frame, before the next (writers use it
            to store the frame's detections and the tracker's state)."""
        res = result or TrackingResult(self.tracks, [], [], [], [])
        res.tracks = self.tracks
        refs = list(rec)
        for i in range(len(res.modes), len(refs)):
            ref = refs[i]
            t0 = time.perf_counter()
            self.last_detections = []
            try:
                frame = rec.frame(ref)
            except (ValueError, OSError) as e:  # an unreadable frame: reported in the result, tracking goes on
                frame, T, mode = None, None, f"failed: {e}"
                self.index += 1
                self.odo.skip()
            if frame is not None:
                try:
                    T, mode = self.step(frame)
                except (ValueError, OSError) as e:  # e.g. no valid depth in range
                    T, mode = None, f"failed: {e}"
            res.seconds.append(time.perf_counter() - t0)
            res.camera_poses.append(T)
            res.modes.append(mode)
            res.detections.append(list(self.last_detections))
            if checkpoint:
                checkpoint(i, ref, res, self)
            if on_frame:
                on_frame(i, mode, res.seconds[-1])
        return res

    def state(self, result: TrackingResult) -> bytes:
        """The tracker's state (odometry, tracks, frame index, whether a detection is due to confirm map poses)
        and ``result`` so far, as a versioned checkpoint of plain data for ``restore`` (``pcdet.io.checkpoint``);
        the detector is not part of it. KISS-ICP's state cannot be saved, so trackers whose odometry uses it
        cannot checkpoint."""
        from .io.checkpoint import pack

        if self.odo.kiss is not None:
            raise InputError("tracking with KISS-ICP odometry cannot be checkpointed (its state cannot be saved); "
                             "use odometry method 'icp'")
        return pack("tracking", {
            "odometry": self.odo.state(), "tracks": [asdict(t) for t in self.tracks],
            "index": self.index, "unconfirmed": self._unconfirmed,
            "result": None if result is None else {
                "camera_poses": result.camera_poses, "modes": result.modes, "seconds": result.seconds,
                "detections": [[asdict(d) for d in ds] for ds in result.detections]}})

    def restore(self, state: bytes, path=None) -> TrackingResult | None:
        """Continue from ``state(result)``: odometry, tracks, frame index and a confirming detection due, as they
        were; returns the result so far, to hand to ``run``. ``InputError`` naming ``path`` for bytes that are no
        tracking checkpoint of this version."""
        from .io.checkpoint import unpack

        d = unpack(state, "tracking", path or "tracking checkpoint")
        try:
            self.odo.load_state(d["odometry"])
            self.tracks = [Track(**{**t, "frames": list(t["frames"]), "poses": list(t["poses"]),
                                    "scores": list(t["scores"]), "modes": list(t["modes"])}) for t in d["tracks"]]
            self.index, self._unconfirmed = int(d["index"]), bool(d["unconfirmed"])
            r = d["result"]
            if r is None:
                return None
            return TrackingResult(self.tracks, list(r["camera_poses"]), list(r["modes"]), list(r["seconds"]),
                                  [[Detection(**x) for x in ds] for ds in r["detections"]])
        except (KeyError, TypeError) as e:
            raise InputError(f"damaged tracking checkpoint ({type(e).__name__}: {e})", path) from None


def frames_by_scene(rec) -> dict[int, list]:
    """The frame refs of ``rec`` per scene id, in recording order (each scene is tracked on its own)."""
    out: dict[int, list] = {}
    for ref in rec:
        out.setdefault(ref.scene_id, []).append(ref)
    return out


class SceneFrames:
    """The frames ``refs`` (frame refs of ``rec``, in order) of one scene of a recording ``rec``, as a recording of
    their own (what ``Tracker.run`` reads)."""

    def __init__(self, rec, refs):
        self.rec, self.images = rec, list(refs)

    def __iter__(self):
        return iter(self.images)

    def __len__(self) -> int:
        return len(self.images)

    def frame(self, ref):
        """The recording's ``Frame`` of ``ref``."""
        return self.rec.frame(ref)


def _track_chunk(shared, refs) -> TrackingResult:
    rec, library, cfg, tcfg = shared
    return Tracker(Detector(library, cfg, workers=1), tcfg).run(SceneFrames(rec, refs))


def write_tracks_json(path, rec, results: dict[int, TrackingResult], pipeline: dict, version: str) -> Path:
    """``tracks.json``: per scene of ``rec``, its frames' image ids, tracks, camera poses and frame modes."""
    scenes, by_scene = [], frames_by_scene(rec)
    for sid, r in results.items():
        refs = by_scene[sid]
        scenes.append({"scene_id": sid, "frames": [f.im_id for f in refs], **r.to_dict()})
    doc = {"pcdet_version": version, "recording": str(rec.root), "format": rec.format, "scenes": scenes,
           "pipeline": pipeline}
    return atomic_write_text(path, json.dumps(doc, indent=1))


def track_recording(rec, library, cfg, tcfg: TrackingConfig | None = None, *, workers: int = 1,
                    executor: str = "local", ray_address: str | None = None, on_frame=None
                    ) -> dict[int, TrackingResult]:
    """Track every scene of ``rec`` (a BOP dataset may hold several sequences; other readers hold one) on its
    own, in this process or spread scene by scene over processes or Ray (``executors.map_chunks``).
    ``on_frame(i, mode, seconds)`` is called per frame when everything runs here."""
    from .executors import map_chunks

    tcfg = tcfg or TrackingConfig()
    scenes = frames_by_scene(rec)
    if executor == "local" and (workers <= 1 or len(scenes) < 2):
        return {sid: Tracker(Detector(library, cfg), tcfg).run(SceneFrames(rec, refs), on_frame)
                for sid, refs in scenes.items()}
    results = map_chunks(_track_chunk, (rec, library, cfg, tcfg), list(scenes.values()), workers=workers,
                         executor=executor, ray_address=ray_address)
    return dict(zip(scenes, results))


def track_into(rec, library, cfg, out, tcfg: TrackingConfig | None = None, *, resume: bool = False,
               version: str = "", record_time: bool = False, on_frame=None) -> dict[int, TrackingResult]:
    """Track every scene of ``rec`` in this process and write into the folder ``out`` what detection writes:
    ``frames/<scene>_<image>.json`` (the objects seen, camera frame) as each frame is done, then
    ``results.csv`` (BOP, rebuilt from the frame files), ``config.toml``, ``failures.json`` and ``tracks.json``.
    After each frame the tracker's state (odometry, map, tracks) goes to ``tracking_state/<scene>.npz``, so a
    killed run continued with ``resume`` picks up where its last checkpoint was and writes the same
    ``results.csv`` as a run that never stopped. ``on_frame(i, mode, seconds)`` after each frame tracked."""
    out = Path(out)
    tcfg = tcfg or TrackingConfig()
    pipeline = cfg.to_dict()
    state_dir = out / "tracking_state"
    state_dir.mkdir(parents=True, exist_ok=True)
    (out / "frames").mkdir(exist_ok=True)
    scenes = frames_by_scene(rec)
    det = Detector(library, cfg)
    results = {}
    for sid, refs in scenes.items():
        tracker = Tracker(det, tcfg)
        ck = state_dir / f"{sid:06d}.npz"
        partial = None
        old = state_dir / f"{sid:06d}.pkl"
        if resume and old.is_file() and not ck.is_file():
            raise InputError("a tracking checkpoint of an earlier pcdet (pickled), which this one does not read: "
                             "start over with --overwrite", old)
        if resume and ck.is_file():
            try:
                partial = tracker.restore(ck.read_bytes(), ck)
            except InputError as e:
                raise InputError(f"{e.problem}: start over with --overwrite", ck) from None
            except OSError as e:
                raise InputError(f"its tracking checkpoint cannot be read ({e}): start over with --overwrite",
                                 ck) from None

        def checkpoint(i, ref, res, trk):
            write_tracked_frame(out, rec, ref, res, i, pipeline=pipeline, version=version)
            atomic_write_bytes(ck, trk.state(res))

        results[sid] = tracker.run(SceneFrames(rec, refs), on_frame, checkpoint=checkpoint, result=partial)
    write_tracking_outputs(out, rec, results, cfg, version=version, record_time=record_time)
    return results


def write_tracked_frame(out, rec, ref, res: TrackingResult, i: int, *, pipeline: dict, version: str) -> None:
    """Frame ``i`` of a scene's result as ``out/frames/<scene>_<image>.json`` (nothing for a failed frame)."""
    from .io.results import write_detections_json
    from .runner import frame_json_path

    if res.modes[i].startswith("failed"):
        return
    info = {"scene_id": ref.scene_id, "im_id": ref.im_id, "source": rec.source(ref), "mode": res.modes[i]}
    if ref.timestamp is not None:
        info["timestamp"] = ref.timestamp
    write_detections_json(frame_json_path(Path(out), ref), info,
                          DetectionResult(res.detections[i], {"track": res.seconds[i]}), pipeline, version)


def write_tracking_outputs(out, rec, results: dict[int, TrackingResult], cfg, *, version: str = "",
                           record_time: bool = False) -> None:
    """``results.csv`` (from the frame files), ``config.toml``, ``failures.json`` and ``tracks.json``."""
    from .config import dump_toml
    from .io.bop import write_results_csv
    from .runner import describe, results_rows

    out = Path(out)
    write_results_csv(out / "results.csv", results_rows(out, list(rec), record_time))
    atomic_write_text(out / "config.toml", dump_toml(cfg))
    scenes = frames_by_scene(rec)
    failed = [{"image": describe(ref), "error": m[8:]} for sid, r in results.items()
              for ref, m in zip(scenes[sid], r.modes) if m.startswith("failed")]
    atomic_write_text(out / "failures.json", json.dumps(failed, indent=1))
    write_tracks_json(out / "tracks.json", rec, results, cfg.to_dict(), version)
