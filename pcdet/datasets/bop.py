"""BOP datasets (https://bop.felk.cvut.cz): ``<root>/<split>/<scene>/{depth,rgb}/<im>.png`` (depth also ``.tif``;
colour also ``.jpg``, or grey in ``gray/``) with ``scene_camera.json``, ``scene_gt.json`` (poses in mm) and
``<root>/models/``."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import InputError
from ..frame import Frame
from ..io.bop import camera_pose_from_bop, pose_from_bop
from ..io.depth import image_size
from ..io.jsonfile import read_json
from .base import FrameRef

BopImage = FrameRef  # one image of a BOP split: (scene_id, im_id)
TARGET_LISTS = {"bop19": "test_targets_bop19.json"}  # --targets NAME: the file in the dataset folder
VISIB_GT_MIN = 0.1  # BOP'19: with a target list, an instance less visible than this is neither found nor missed


class BopDataset:
    """Lazy access to the images of one split of a BOP dataset (a ``Recording``).

    ``root`` may be the dataset folder (holding ``models/`` and a split folder such as ``test/``) or a split
    folder itself (holding scene folders). Camera poses come from ``cam_R_w2c`` / ``cam_t_w2c`` in
    ``scene_camera.json`` when present (``pcdet synth --sequence`` writes them). ``restrict_to`` narrows it to the
    images, objects and counts of a BOP target list (``test_targets_bop19.json``).
    """

    format = "bop"

    def __init__(self, root, split: str | None = None):
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"{root}: dataset folder not found")
        if _is_split(root):
            self.split_dir, self.root = root, root.parent
        else:
            cands = [root / split] if split else sorted(p for p in root.iterdir() if p.is_dir() and _is_split(p))
            cands = [c for c in cands if c.is_dir() and _is_split(c)]
            if not cands:
                raise InputError("no BOP split folder (scene folders with scene_camera.json) found", root)
            self.split_dir, self.root = cands[0], root
        self._json: dict[tuple[int, str], dict] = {}
        self.target_list: dict[tuple[int, int], dict[int, int]] | None = None  # see restrict_to
        self.target_file: Path | None = None
        self.models_dir = self.root / "models" if (self.root / "models").is_dir() else None
        cam = self.root / "camera.json"
        self.base_camera = read_json(cam) if cam.is_file() else {}
        self.images: list[BopImage] = []
        for sdir in sorted(p for p in self.split_dir.iterdir() if p.is_dir() and p.name.isdigit()):
            sc = sdir / "scene_camera.json"
            if not sc.is_file():
                continue
            ids = sorted(int(k) for k in read_json(sc))
            self.images += [BopImage(int(sdir.name), i) for i in ids]

    @classmethod
    def detect(cls, path: Path) -> bool:
        """Whether ``path`` is a BOP split or a dataset folder holding one."""
        return _is_split(path) or any(p.is_dir() and _is_split(p) for p in path.iterdir())

    def __len__(self) -> int:
        return len(self.images)

    def source(self, img: BopImage) -> str:
        """The depth PNG an image is read from."""
        return str(self.depth_path(img))

    def camera_poses(self) -> dict[BopImage, np.ndarray] | None:
        """``T_world_cam`` per image from ``cam_R_w2c`` / ``cam_t_w2c`` (mm), or None if any image lacks them."""
        poses = {}
        for img in self.images:
            e = self._scene_json(img.scene_id, "scene_camera.json").get(str(img.im_id), {})
            if "cam_R_w2c" not in e or "cam_t_w2c" not in e:
                return None
            poses[img] = camera_pose_from_bop(e)
        return poses

    def __iter__(self):
        return iter(self.images)

    def scene_dir(self, scene_id: int) -> Path:
        """The folder of one scene of the split."""
        return self.split_dir / f"{scene_id:06d}"

    def _scene_json(self, scene_id: int, name: str) -> dict:
        """A scene's JSON file, read once per dataset object (an empty dict when the file is absent)."""
        key = (scene_id, name)
        if key not in self._json:
            p = self.scene_dir(scene_id) / name
            self._json[key] = read_json(p) if p.is_file() else {}
        return self._json[key]

    def depth_path(self, img: BopImage) -> Path:
        """The depth image of an image: ``depth/<im>.png``, or ``depth/<im>.tif`` where only that exists (ITODD's
        16-bit TIFFs)."""
        png = self.scene_dir(img.scene_id) / "depth" / f"{img.im_id:06d}.png"
        tif = png.with_suffix(".tif")
        return tif if not png.is_file() and tif.is_file() else png

    def rgb_path(self, img: BopImage) -> Path | None:
        """The colour (or grey) image of an image, or None when the dataset has none."""
        for sub, ext in (("rgb", ".png"), ("rgb", ".jpg"), ("gray", ".png"), ("gray", ".tif")):
            p = self.scene_dir(img.scene_id) / sub / f"{img.im_id:06d}{ext}"
            if p.is_file():
                return p
        return None

    def camera(self, img: BopImage) -> Camera:
        """The image's camera from scene_camera.json; the size comes from camera.json or the depth PNG's header."""
        entry = self._scene_json(img.scene_id, "scene_camera.json").get(str(img.im_id))
        src = self.scene_dir(img.scene_id) / "scene_camera.json"
        if entry is None:
            raise InputError(f"no entry for image {img.im_id}", src)
        w, h = self.base_camera.get("width"), self.base_camera.get("height")
        if w is None or h is None:  # no camera.json: the PNG header has the size (no decoding)
            w, h = image_size(self.depth_path(img))
        return Camera.from_dict(dict(entry), path=src, width=w, height=h)

    def frame(self, img: BopImage) -> Frame:
        """The image as a ``Frame`` (depth in metres, colour when present, its BOP ids in ``info``)."""
        rgb = self.rgb_path(img)
        return Frame.from_depth_png(self.depth_path(img), self.camera(img), rgb_path=rgb,
                                    info={"scene_id": img.scene_id, "im_id": img.im_id})

    def gt(self, img: BopImage) -> list[dict]:
        """Ground truth of one image: ``[{"obj_id", "T_cam_model" (4, 4, m), "visib_fract" or None}]``."""
        entries = self._scene_json(img.scene_id, "scene_gt.json").get(str(img.im_id), [])
        infos = self._scene_json(img.scene_id, "scene_gt_info.json").get(str(img.im_id), [])
        out = []
        for k, e in enumerate(entries):
            vf = infos[k].get("visib_fract") if k < len(infos) else None
            out.append({"obj_id": int(e["obj_id"]), "T_cam_model": pose_from_bop(e), "visib_fract": vf})
        return out

    def scored_gt(self, img: BopImage) -> list[dict]:
        """The ground truth that is scored (``gt``'s entries): every instance, or with a target list in use
        (``restrict_to``) the listed objects' instances at least ``VISIB_GT_MIN`` visible, as BOP'19 scores (an
        instance without ``visib_fract`` counts)."""
        gts = self.gt(img)
        if self.target_list is None:
            return gts
        wanted = self.target_list[(img.scene_id, img.im_id)]
        return [g for g in gts if g["obj_id"] in wanted and (g["visib_fract"] is None
                                                              or g["visib_fract"] >= VISIB_GT_MIN)]

    def targets(self, img: BopImage) -> dict[int, int]:
        """``{obj_id: instance count}`` (BOP's localisation task): from the target list when one is in use
        (``restrict_to``), else from scene_gt.json."""
        if self.target_list is not None:
            return dict(self.target_list[(img.scene_id, img.im_id)])
        t: dict[int, int] = {}
        for g in self.gt(img):
            t[g["obj_id"]] = t.get(g["obj_id"], 0) + 1
        return t

    def restrict_to(self, spec: str) -> None:
        """Keep only the images of a BOP target list, whose objects and counts become ``targets``: ``spec`` is
        "bop19" (the dataset's ``test_targets_bop19.json``, the images BOP's challenges evaluate) or the path of
        a file in that form (``read_target_list``). ``InputError`` names the file when it is missing, malformed
        or lists an image the split does not hold."""
        path = self.root / TARGET_LISTS[spec] if spec in TARGET_LISTS else Path(spec)
        if not path.is_file():
            raise InputError("target list not found" + (f" (--targets {spec} reads {TARGET_LISTS[spec]} in the "
                                                        "dataset folder)" if spec in TARGET_LISTS else ""), path)
        listed = read_target_list(path)
        held = set(self.images)
        missing = [k for k in listed if BopImage(*k) not in held]
        if missing:
            raise InputError(f"lists {len(missing)} image(s) that {self.split_dir} does not hold (the first: scene "
                             f"{missing[0][0]} image {missing[0][1]})", path)
        self.images = [img for img in self.images if (img.scene_id, img.im_id) in listed]
        self.target_list = listed
        self.target_file = path


def read_target_list(path) -> dict[tuple[int, int], dict[int, int]]:
    """``{(scene_id, im_id): {obj_id: inst_count}}`` from a BOP target list: a JSON list of ``{"scene_id",
    "im_id", "obj_id", "inst_count"}`` (BOP'19, ``test_targets_bop19.json``; ``inst_count`` counts the instances
    at least 10 % visible). ``InputError`` names the file and the first bad entry."""
    doc = read_json(path, expect_object=False, what="target list")
    if not isinstance(doc, list):
        raise InputError("a BOP target list is a JSON list of {scene_id, im_id, obj_id, inst_count}", path)
    out: dict[tuple[int, int], dict[int, int]] = {}
    for n, e in enumerate(doc):
        try:
            s, i, o, c = (e[k] for k in ("scene_id", "im_id", "obj_id", "inst_count"))
        except (TypeError, KeyError):
            raise InputError(f"entry {n} is not {{scene_id, im_id, obj_id, inst_count}} (BOP'19 targets; a "
                             "BOP'24 list names no objects)", path) from None
        if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in (s, i, o, c)) or c < 1:
            raise InputError(f"entry {n}: ids must be whole numbers >= 0 and inst_count >= 1, got {e}", path)
        if o in out.setdefault((s, i), {}):
            raise InputError(f"entry {n}: scene {s} image {i} lists object {o} twice", path)
        out[(s, i)][o] = c
    if not out:
        raise InputError("the target list is empty", path)
    return out


def _is_split(p: Path) -> bool:
    return p.is_dir() and any((s / "scene_camera.json").is_file() for s in p.iterdir() if s.is_dir())
