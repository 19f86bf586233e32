"""BOP datasets (https://bop.felk.cvut.cz): ``<root>/<split>/<scene>/{depth,rgb}/<im>.png`` with
``scene_camera.json``, ``scene_gt.json`` (poses in mm) and ``<root>/models/``."""
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


class BopDataset:
    """Lazy access to the images of one split of a BOP dataset (a ``Recording``).

    ``root`` may be the dataset folder (holding ``models/`` and a split folder such as ``test/``) or a split
    folder itself (holding scene folders). Camera poses come from ``cam_R_w2c`` / ``cam_t_w2c`` in
    ``scene_camera.json`` when present (``pcdet synth --sequence`` writes them).
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
        """The depth PNG of an image."""
        return self.scene_dir(img.scene_id) / "depth" / f"{img.im_id:06d}.png"

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

    def targets(self, img: BopImage) -> dict[int, int]:
        """``{obj_id: instance count}`` from scene_gt.json (BOP's localisation task)."""
        t: dict[int, int] = {}
        for g in self.gt(img):
            t[g["obj_id"]] = t.get(g["obj_id"], 0) + 1
        return t


def _is_split(p: Path) -> bool:
    return p.is_dir() and any((s / "scene_camera.json").is_file() for s in p.iterdir() if s.is_dir())
