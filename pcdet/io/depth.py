"""16-bit depth PNGs and RGB images, with validation that names the file and the problem."""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from ..errors import InputError
from .atomic import atomic_write_bytes


def _open(path) -> Image.Image:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: image not found")
    try:
        im = Image.open(path)
        im.load()
    except UnidentifiedImageError:
        raise InputError("not a readable image", path) from None
    except (OSError, SyntaxError, ValueError) as e:
        raise InputError(f"image is truncated or corrupt ({e})", path) from None
    return im


def image_size(path) -> tuple[int, int]:
    """(width, height) of an image file, from its header (no decoding)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: image not found")
    try:
        with Image.open(path) as im:
            return im.size
    except (UnidentifiedImageError, OSError) as e:
        raise InputError(f"not a readable image ({e})", path) from None


def read_depth_png(path) -> np.ndarray:
    """Read a single-channel 16-bit depth image.

    Returns
    -------
    (H, W) uint16 raw depth values (convert with the camera's ``depth_scale``).

    Raises ``InputError`` for 8-bit, colour or float images, which are not depth maps in any format pcdet reads.
    """
    im = _open(path)
    if im.mode in ("I;16", "I;16B", "I;16L"):
        return np.asarray(im, dtype=np.uint16).copy()
    if im.mode == "I":
        a = np.asarray(im)
        if a.min() < 0 or a.max() > 65535:
            raise InputError("depth image holds values outside the 16-bit range", path)
        return a.astype(np.uint16)
    raise InputError(f"depth image is {describe_mode(im.mode)}; expected a single-channel 16-bit PNG (raw depth "
                     "units, such as millimetres)", path)


MODE_NAMES = {"1": "a 1-bit black-and-white image", "L": "an 8-bit greyscale image", "LA": "an 8-bit greyscale "
              "image with transparency", "P": "a palette (indexed-colour) image", "RGB": "a colour (RGB) image",
              "RGBA": "a colour image with transparency (RGBA)", "CMYK": "a CMYK colour image",
              "YCbCr": "a colour (YCbCr) image", "F": "a 32-bit floating-point image", "I": "a 32-bit integer image"}


def describe_mode(mode: str) -> str:
    """What a person calls an image of Pillow's ``mode``: "an 8-bit greyscale image" for "L"."""
    return MODE_NAMES.get(mode, f"an image of kind {mode!r}")


def read_rgb(path) -> np.ndarray:
    """(H, W, 3) uint8 colour image."""
    im = _open(path)
    return np.asarray(im.convert("RGB"))


def write_depth_png(path, raw: np.ndarray) -> Path:
    """Write (H, W) uint16 raw depth atomically as a 16-bit PNG."""
    raw = np.asarray(raw)
    if raw.dtype != np.uint16 or raw.ndim != 2:
        raise InputError(f"depth to write must be a 2D uint16 array, got {raw.dtype} {raw.shape}", path)
    buf = io.BytesIO()
    Image.fromarray(raw).save(buf, format="PNG")
    return atomic_write_bytes(path, buf.getvalue())


def write_png(path, rgb: np.ndarray) -> Path:
    """Write an (H, W, 3) uint8 image atomically."""
    buf = io.BytesIO()
    Image.fromarray(np.asarray(rgb, dtype=np.uint8)).save(buf, format="PNG")
    return atomic_write_bytes(path, buf.getvalue())
