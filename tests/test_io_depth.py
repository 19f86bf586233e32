"""Depth PNG reading: the bad inputs each give one clear error naming the file."""
import numpy as np
import pytest
from PIL import Image

from pcdet.errors import InputError
from pcdet.io.depth import read_depth_png, write_depth_png


def test_roundtrip_16bit(tmp_path, rng):
    raw = rng.integers(0, 65535, (48, 64)).astype(np.uint16)
    write_depth_png(tmp_path / "d.png", raw)
    np.testing.assert_array_equal(read_depth_png(tmp_path / "d.png"), raw)


def test_truncated_png(tmp_path, rng):
    raw = rng.integers(0, 65535, (120, 160)).astype(np.uint16)
    write_depth_png(tmp_path / "d.png", raw)
    data = (tmp_path / "d.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"cut\.png: image is truncated or corrupt"):
        read_depth_png(tmp_path / "cut.png")


def test_8bit_and_rgb_are_refused(tmp_path):
    Image.fromarray(np.zeros((10, 10), np.uint8)).save(tmp_path / "gray8.png")
    Image.fromarray(np.zeros((10, 10, 3), np.uint8)).save(tmp_path / "rgb.png")
    with pytest.raises(InputError, match=r"gray8\.png: depth image is an 8-bit greyscale image; expected a "
                                         r"single-channel 16-bit PNG"):
        read_depth_png(tmp_path / "gray8.png")
    with pytest.raises(InputError, match=r"rgb\.png: depth image is a colour \(RGB\) image"):
        read_depth_png(tmp_path / "rgb.png")


def test_not_an_image(tmp_path):
    (tmp_path / "x.png").write_text("hello")
    with pytest.raises(InputError, match=r"x\.png: not a readable image"):
        read_depth_png(tmp_path / "x.png")


def test_write_refuses_wrong_dtype(tmp_path):
    with pytest.raises(InputError, match="uint16"):
        write_depth_png(tmp_path / "d.png", np.zeros((4, 4), np.float32))
