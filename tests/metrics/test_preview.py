"""Previews: uint8 RGB of the right shape, the stated tone mapper, the magma colormap."""

from __future__ import annotations

import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from metrics.checks import MetricError
from metrics.preview import error_map_preview, tonemap_preview
from metrics.tonemap import SRGB_LINEAR_LIMIT, srgb_encode, to_display_srgb


def test_tonemap_preview_dtype_shape_and_values():
    img = np.array([[[0.0, 0.5, 1.0], [2.0, -1.0, math.nan]]], np.float32)
    out = tonemap_preview(img)
    assert out.dtype == np.uint8 and out.shape == (1, 2, 3)
    # sRGB(0.5) = 1.055 * 0.5^(1/2.4) - 0.055 = 0.7354
    assert out[0, 0].tolist() == [0, 188, 255]
    assert out[0, 1].tolist() == [0, 0, 0]  # a non-finite pixel shows black


def test_tonemap_exposure_is_in_stops():
    img = np.full((2, 2, 3), 0.25, np.float32)
    assert np.array_equal(tonemap_preview(img, exposure=1.0), tonemap_preview(img * 2))


def test_tonemap_is_monotone_and_handles_grey_and_alpha():
    ramp = np.linspace(0, 1.5, 64, dtype=np.float32)[None, :, None]
    out = tonemap_preview(ramp)
    assert out.shape == (1, 64, 3) and np.all(np.diff(out[0, :, 0].astype(int)) >= 0)
    rgba = np.ones((2, 2, 4), np.float32)
    assert tonemap_preview(rgba).shape == (2, 2, 3)
    with pytest.raises(MetricError):
        tonemap_preview(np.ones((2, 2, 2), np.float32))


def test_the_srgb_encoding_is_colour_sciences_bitwise():
    """The encoder the project took from colour-science before: bitwise the same on every
    1009th float32 in [0, 1] (all exponents) and around the linear segment's end; the
    formula evaluated in float32 (planted) is told apart."""
    with warnings.catch_warnings():   # its optional features' warnings
        warnings.simplefilter("ignore")
        import colour
    one = int(np.float32(1.0).view(np.uint32))
    limit = int(np.float32(SRGB_LINEAR_LIMIT).view(np.uint32))
    bits = np.concatenate([np.arange(0, one, 1009), np.arange(limit - 64, limit + 64), [one]])
    linear = bits.astype(np.uint32).view(np.float32)
    expected = colour.cctf_encoding(linear, function="sRGB").view(np.uint64)
    assert np.array_equal(srgb_encode(linear).view(np.uint64), expected)
    single = np.float32
    planted = np.where(linear <= single(SRGB_LINEAR_LIMIT), linear * single(12.92),
                       single(1.055) * linear ** single(1 / 2.4) - single(0.055))
    assert not np.array_equal(planted.astype(np.float64).view(np.uint64), expected)


def test_display_transform_is_in_unit_range():
    out = to_display_srgb(np.array([[[-3.0, 0.2, 50.0]]], np.float32))
    assert out.dtype == np.float32 and out.min() >= 0.0 and out.max() <= 1.0


def test_error_map_preview_uses_magma():
    error = np.array([[0.0, 0.5, 1.0, 7.0, math.nan]], np.float32)
    out = error_map_preview(error)
    assert out.dtype == np.uint8 and out.shape == (1, 5, 3)
    assert out[0, 0].tolist() == [0, 0, 4]          # magma(0)
    assert out[0, 2].tolist() == [252, 253, 191]    # magma(1)
    assert np.array_equal(out[0, 3], out[0, 2])     # clamped above vmax
    assert np.array_equal(out[0, 4], out[0, 2])     # NaN painted as the worst
    assert abs(int(out[0, 1, 0]) - round(0.716 * 255)) <= 2  # magma(0.5) is reddish
    # Luminance grows along the map (perceptually ordered).
    ramp = error_map_preview(np.linspace(0, 1, 32)[None]).astype(float)
    luminance = ramp[0] @ np.array([0.2126, 0.7152, 0.0722])
    assert np.all(np.diff(luminance) > 0)


def test_error_map_preview_scale_and_shapes():
    error = np.full((3, 4, 1), 2.0, np.float32)
    assert np.array_equal(error_map_preview(error, vmax=4.0),
                          error_map_preview(np.full((3, 4), 0.5)))
    with pytest.raises(MetricError):
        error_map_preview(np.zeros((3, 4, 3)))
    with pytest.raises(MetricError):
        error_map_preview(np.zeros((3, 4)), vmax=0.0)


def test_metrics_imports_no_renderer_or_service_code_nor_plotting():
    """Scoring a render (its preview, its tone-mapped PSNR) loads neither the project's
    other layers nor Matplotlib or SciPy (seconds in every render process)."""
    code = (
        "import sys\n"
        "import metrics.errors, metrics.flip, metrics.imageio, metrics.preview, "
        "metrics.statistics\n"
        "import numpy as np\n"
        "image = np.ones((2, 2, 3), np.float32)\n"
        "metrics.preview.tonemap_preview(image)\n"
        "metrics.errors.psnr_tonemapped(image, 0.5 * image)\n"
        "bad = [m for m in sys.modules if m.split('.')[0] in "
        "('jobs', 'service', 'renderers', 'mitsuba', 'drjit', 'matplotlib', 'scipy')]\n"
        "print(','.join(bad))\n"
    )
    root = Path(__file__).resolve().parents[2]
    done = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True,
                          text=True, check=True)
    assert done.stdout.strip() == ""
