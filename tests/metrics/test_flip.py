"""The FLIP wrapper: fixed exposures per reference, zero for identical images, no printing."""

from __future__ import annotations

import math

import flip_evaluator
import numpy as np
import pytest

from metrics.checks import MetricError
from metrics.errors import image_metrics
from metrics.flip import FlipExposures, flip_hdr, flip_ldr, hdr_exposures


@pytest.fixture(scope="module")
def ref() -> np.ndarray:
    rng = np.random.default_rng(0)
    image = rng.uniform(0.0, 1.0, (32, 32, 3)).astype(np.float32)
    image[8:16, 8:16] *= 20.0  # a bright patch so the exposure range is non-trivial
    return image


@pytest.fixture(scope="module")
def exposures(ref) -> FlipExposures:
    return hdr_exposures(ref)


def _noisy(ref: np.ndarray, seed: int, sigma: float = 0.2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (ref * (1.0 + sigma * rng.standard_normal(ref.shape))).clip(0).astype(np.float32)


def test_exposures_are_flips_own_and_fixed_per_reference(ref, exposures):
    assert exposures.start <= exposures.stop
    assert hdr_exposures(ref) == exposures  # deterministic: one range per reference
    test = _noisy(ref, 1)
    _, default_mean, used = flip_evaluator.evaluate(ref, test, "HDR", applyMagma=False)
    assert (used["startExposure"], used["stopExposure"]) == pytest.approx(tuple(exposures))
    assert flip_hdr(ref, test, exposures)[0] == pytest.approx(default_mean)


def test_identical_images_score_zero(ref, exposures):
    mean, error_map = flip_hdr(ref, ref.copy(), exposures)
    assert mean == 0.0 and error_map.shape == (32, 32) and not error_map.any()
    assert flip_ldr(ref, ref.copy())[0] == 0.0


def test_different_images_score_above_zero(ref, exposures):
    test = _noisy(ref, 2)
    mean, error_map = flip_hdr(ref, test, exposures)
    assert mean > 0.0
    assert error_map.dtype == np.float32
    assert 0.0 <= error_map.min() and error_map.max() <= 1.0
    assert float(error_map.mean()) == pytest.approx(mean, rel=1e-4)
    ldr_mean, ldr_map = flip_ldr(ref, test)
    assert ldr_mean > 0.0 and ldr_map.shape == (32, 32)


def test_the_same_exposures_serve_every_run(ref, exposures):
    # Runs against one reference reuse its exposures; other exposures change the score,
    # so passing them really matters.
    first, second = _noisy(ref, 3), _noisy(ref, 4)
    assert flip_hdr(ref, first, exposures)[0] == flip_hdr(ref, first, tuple(exposures))[0]
    assert flip_hdr(ref, second, exposures)[0] > 0.0
    shifted = (exposures.start - 3.0, exposures.stop + 3.0)
    assert flip_hdr(ref, first, shifted)[0] != pytest.approx(flip_hdr(ref, first, exposures)[0])


def test_nonfinite_and_negative_pixels_are_zeroed(ref, exposures):
    test = _noisy(ref, 5)
    zeroed = test.copy()
    zeroed[3, 4] = 0.0
    broken = test.copy()
    broken[3, 4, 1] = math.nan
    negative = test.copy()
    negative[3, 4] = -5.0
    expected = flip_hdr(ref, zeroed, exposures)[0]
    assert flip_hdr(ref, broken, exposures)[0] == expected
    assert flip_hdr(ref, negative, exposures)[0] == expected
    assert flip_ldr(ref, broken)[0] == flip_ldr(ref, zeroed)[0]


def test_dark_and_black_references_do_not_end_the_process(ref, exposures, capfd):
    # FLIP's heuristic exits the process for references this dark; ours rescales.
    scale = 1e-9
    dark = hdr_exposures(ref * scale)
    assert dark.start == pytest.approx(exposures.start - math.log2(scale), abs=1e-3)
    assert dark.stop == pytest.approx(exposures.stop - math.log2(scale), abs=1e-3)
    black = np.zeros((8, 8, 3), np.float32)
    assert hdr_exposures(black) == (0.0, 0.0)
    assert flip_hdr(black, black + 0.5, hdr_exposures(black))[0] > 0.0
    assert capfd.readouterr().out == ""


def test_flip_prints_nothing(ref, exposures, capfd):
    flip_hdr(ref, _noisy(ref, 6), exposures)
    flip_ldr(ref, _noisy(ref, 6))
    assert capfd.readouterr().out == ""


@pytest.mark.parametrize("bad", [(1.0, 0.0), (math.nan, 1.0), (0.0, math.inf), (1.0,)])
def test_invalid_exposures_raise_instead_of_exiting(ref, bad):
    with pytest.raises(MetricError, match="exposures"):
        flip_hdr(ref, ref, bad)


def test_shape_checks(ref, exposures):
    with pytest.raises(MetricError, match="does not match"):
        flip_hdr(ref, ref[:16], exposures)
    with pytest.raises(MetricError, match="3 \\(RGB\\)"):
        flip_ldr(ref[..., :1], ref[..., :1])


def test_image_metrics_with_flip(ref, exposures):
    test = _noisy(ref, 7)
    result = image_metrics(test, ref, flip_exposures=exposures, return_maps=True)
    assert result["flip_exposures"] == pytest.approx(list(exposures))
    assert result["flip_hdr"] == pytest.approx(flip_hdr(ref, test, exposures)[0])
    assert result["flip_ldr"] == pytest.approx(flip_ldr(ref, test)[0])
    assert set(result["error_maps"]) == {"relative_squared_error", "flip_hdr", "flip_ldr"}
    # Without stored exposures they are computed from the reference: same result.
    assert image_metrics(test, ref)["flip_hdr"] == pytest.approx(result["flip_hdr"])
