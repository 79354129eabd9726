"""EXR/PNG files: bit-exact round trips, one-line errors for bad files, atomic writes."""

from __future__ import annotations

import math
import os

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from metrics import imageio
from metrics.imageio import ImageReadError, read_exr, write_exr, write_png


def _awkward_floats(shape: tuple[int, ...]) -> np.ndarray:
    """Random float32 with NaN, +-Inf, negatives, subnormals and extremes."""
    rng = np.random.default_rng(0)
    img = rng.standard_normal(shape).astype(np.float32) * 100
    flat = img.reshape(-1)
    flat[:6] = [math.nan, math.inf, -math.inf, 1e-42, np.finfo(np.float32).max, -0.0]
    return img


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and np.array_equal(a.view(np.uint32), b.view(np.uint32))


def test_rgb_round_trip_is_bit_exact(tmp_path):
    img = _awkward_floats((13, 17, 3))
    path = tmp_path / "img.exr"
    write_exr(path, img)
    back = read_exr(path)
    assert back.shape == (13, 17, 3) and _same_bits(back, img)


def test_single_channel_and_named_layer_round_trip(tmp_path):
    grey = _awkward_floats((5, 6))
    write_exr(tmp_path / "y.exr", grey)
    back = read_exr(str(tmp_path / "y.exr"))
    assert back.shape == (5, 6, 1) and _same_bits(back[..., 0], grey)

    variance = np.abs(_awkward_floats((5, 6, 3)))
    write_exr(tmp_path / "v.exr", variance, channels=["variance.R", "variance.G", "variance.B"])
    assert _same_bits(read_exr(tmp_path / "v.exr", layer="variance"), variance)
    with pytest.raises(ImageReadError, match="no R/G/B or Y"):
        read_exr(tmp_path / "v.exr")


def test_rgba_reads_as_rgb(tmp_path):
    rgba = _awkward_floats((4, 4, 4))
    write_exr(tmp_path / "a.exr", rgba)
    assert _same_bits(read_exr(tmp_path / "a.exr"), np.ascontiguousarray(rgba[..., :3]))


def _one_line_read_error(path) -> str:
    with pytest.raises(ImageReadError) as info:
        read_exr(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    return message


def test_missing_file(tmp_path):
    assert "no such file" in _one_line_read_error(tmp_path / "missing.exr")


def test_random_bytes(tmp_path):
    path = tmp_path / "noise.exr"
    path.write_bytes(np.random.default_rng(1).bytes(4096))
    assert "not an OpenEXR file" in _one_line_read_error(path)


@pytest.mark.parametrize("keep", [0.5, 0.99])
def test_truncated_exr(tmp_path, keep):
    path = tmp_path / "cut.exr"
    write_exr(path, np.random.default_rng(2).random((32, 32, 3), dtype=np.float32))
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    _one_line_read_error(path)


def test_exr_without_colour_channels(tmp_path):
    path = tmp_path / "depth.exr"
    write_exr(path, np.ones((3, 3, 1), np.float32), channels=["Z"])
    assert "found: Z" in _one_line_read_error(path)


def test_write_exr_validates_channel_names(tmp_path):
    with pytest.raises(ValueError, match="distinct"):
        write_exr(tmp_path / "x.exr", np.ones((2, 2, 3)), channels=["R", "R", "B"])
    with pytest.raises(ValueError, match="by default"):
        write_exr(tmp_path / "x.exr", np.ones((2, 2, 2)))
    assert list(tmp_path.iterdir()) == []


def test_writes_are_atomic(tmp_path, monkeypatch):
    path = tmp_path / "img.exr"
    original = np.ones((4, 4, 3), np.float32)
    write_exr(path, original)
    write_exr(path, original * 2)  # overwriting works
    assert read_exr(path)[0, 0, 0] == 2.0

    class CrashingFile:
        """Writes half a file, then fails, like a crash mid-write."""

        def __init__(self, *args, **kwargs):
            pass

        def write(self, name):
            with open(name, "wb") as handle:
                handle.write(b"v/1\x01partial")
            raise OSError("disk full")

    monkeypatch.setattr(imageio.OpenEXR, "File", CrashingFile)
    with pytest.raises(OSError, match="disk full"):
        write_exr(path, original * 3)
    monkeypatch.undo()
    assert read_exr(path)[0, 0, 0] == 2.0  # the old file is intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["img.exr"]  # no temp file left


def test_written_files_respect_the_umask(tmp_path):
    path = tmp_path / "img.exr"
    write_exr(path, np.ones((2, 2, 3), np.float32))
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask


def test_png_round_trip(tmp_path):
    rgb = np.random.default_rng(3).integers(0, 256, (7, 9, 3), dtype=np.uint8)
    path = tmp_path / "p.png"
    write_png(path, rgb)
    with Image.open(path) as png:
        assert png.mode == "RGB"
        assert np.array_equal(np.asarray(png), rgb)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.png"]


def test_png_rejects_float_images(tmp_path):
    with pytest.raises(ValueError, match="uint8"):
        write_png(tmp_path / "p.png", np.zeros((2, 2, 3), np.float32))


def test_openexr_is_the_3x_api():
    assert hasattr(OpenEXR, "File")
