"""Noise-corrected per-pixel relative-bias maps (metrics/bias_maps.py).

The v1 image of the adaptive protocol and the reference are both noisy; a map
that does not subtract their variances calls an unbiased but noisy image
biased. The synthetic images here carry noise whose squared size is exactly
its stated variance (random signs of a fixed amplitude), so "every pixel"
statements hold exactly, not in probability.
"""

from __future__ import annotations

import numpy as np
import pytest

from metrics.bias_maps import (
    LUMINANCE_FLOOR,
    authors_bias_map,
    bias_map,
    passes,
    relative_mse_bias_map,
)

EPS = 0.05
METRIC_EPS = 0.01
DEFINITIONS = ("relative-mse", "authors")


def _reference(rng: np.random.Generator, shape=(24, 20)) -> np.ndarray:
    """A coloured reference bright enough that R^2 >> the metric epsilon (channels in
    ratio 1 : 0.8 : 0.6, so no channel exceeds 1.2 x the luminance)."""
    return rng.uniform(1.0, 4.0, (*shape, 1)) * np.array([1.0, 0.8, 0.6])


def _signed_noise(rng: np.random.Generator, sigma: np.ndarray) -> np.ndarray:
    """Noise of variance sigma^2 whose every draw has (noise)^2 = sigma^2."""
    return sigma * rng.choice([-1.0, 1.0], size=sigma.shape)


def _map(definition, v, r, var_v=None, var_r=None):
    return bias_map(definition, v, r, METRIC_EPS, v_variance=var_v, ref_variance=var_r)


@pytest.mark.parametrize("definition", DEFINITIONS)
def test_an_unbiased_noisy_image_passes_everywhere_once_the_noise_is_subtracted(definition):
    """V = R + 10 % noise, against a reference with 0.5 % noise of its own."""
    rng = np.random.default_rng(1)
    ref = _reference(rng)
    var_v, var_r = (0.1 * ref) ** 2, (0.005 * ref) ** 2
    v = ref + _signed_noise(rng, np.sqrt(var_v))
    r = ref + _signed_noise(rng, np.sqrt(var_r))
    # Without the correction the noise looks like bias: no pixel passes (the old map).
    assert not passes(_map(definition, v, r), EPS).any()
    # With it, what is left is at most the cross term 2 sigma_V sigma_R (opposite signs),
    # sqrt(2 * 0.1 * 0.005) = 3.2 % of R -- below 5 % even over the luminance.
    assert passes(_map(definition, v, r, var_v, var_r), EPS).all()


@pytest.mark.parametrize("definition", DEFINITIONS)
def test_gaussian_noise_with_an_estimated_variance_passes_far_more_often(definition):
    """V as the mean of 16 noisy passes, its variance estimated from them (as render_v1)."""
    rng = np.random.default_rng(2)
    ref = _reference(rng, (48, 48))
    passes_ = ref + rng.normal(0.0, 0.2 * ref, (16, *ref.shape))   # 5 % noise on the mean
    v = passes_.mean(axis=0)
    var_v = passes_.var(axis=0, ddof=1) / 16
    raw = passes(_map(definition, v, ref), EPS).mean()
    corrected = passes(_map(definition, v, ref, var_v), EPS).mean()
    # (seed 2: relative-mse 0.60 -> 0.88, authors 0.36 -> 0.62; a noisy variance
    # estimate with 15 degrees of freedom cannot make every pixel pass)
    assert corrected > raw + 0.2 and corrected > 0.6, (raw, corrected)


@pytest.mark.parametrize("definition", DEFINITIONS)
def test_a_planted_ten_percent_bias_fails_exactly_in_its_region(definition):
    rng = np.random.default_rng(3)
    ref = _reference(rng)
    var_v = (0.03 * ref) ** 2
    v = ref + _signed_noise(rng, np.sqrt(var_v))
    region = np.zeros(ref.shape[:2], bool)
    region[5:12, 3:9] = True
    v[region] += 0.1 * ref[region]
    ok = passes(_map(definition, v, ref, var_v, np.zeros_like(ref)), EPS)
    assert np.array_equal(ok, ~region)


def test_relative_mse_is_the_root_of_the_pixel_relative_squared_error_minus_noise():
    ref = np.full((2, 2, 3), 2.0)
    test = ref.copy()
    test[0, 0] = [3.0, 2.0, 2.0]            # one channel off by 1
    bias = relative_mse_bias_map(test, ref, eps=0.01)
    assert bias[0, 0] == pytest.approx(np.sqrt((1 / (4 + 0.01)) / 3), rel=1e-5)
    assert np.all(bias.ravel()[1:] == 0)
    var = np.full_like(ref, 0.1)
    corrected = relative_mse_bias_map(test, ref, 0.01, v_variance=var, ref_variance=var)
    assert corrected[0, 0] == pytest.approx(np.sqrt((1 - 6 * 0.1) / 4.01 / 3), rel=1e-5)
    assert np.all(corrected.ravel()[1:] == 0)   # clipped at 0, never negative


def test_authors_definition_is_per_channel_over_reference_luminance():
    ref = np.zeros((1, 3, 3))
    ref[0, 0] = [1.0, 1.0, 1.0]            # luminance 1
    ref[0, 1] = [2.0, 0.0, 0.0]            # luminance 0.598
    test = ref.copy()
    test[0, 0, 2] += 0.04                  # blue off by 4 % of the luminance: passes at 0.05
    test[0, 1, 1] += 0.04                  # green off by 0.04 / 0.598 = 6.7 %: fails
    test[0, 2] = [0.1, 0.1, 0.1]           # black reference: never passes
    bias = authors_bias_map(test, ref)
    assert bias[0, 0] == pytest.approx(0.04, rel=1e-5)
    assert bias[0, 1] == pytest.approx(0.04 / 0.598, rel=1e-5)
    assert np.isinf(bias[0, 2])
    assert passes(bias, EPS).tolist() == [[True, False, False]]
    # The floor: a reference at or below it never passes, even when V equals it.
    tiny = np.full((1, 1, 3), LUMINANCE_FLOOR / 2)
    assert not passes(authors_bias_map(tiny, tiny), EPS).any()


@pytest.mark.parametrize("definition", DEFINITIONS)
def test_non_finite_pixels_never_pass(definition):
    ref = np.ones((2, 2, 3))
    test = ref.copy()
    test[0, 0, 1] = np.nan
    test[1, 1, 0] = np.inf
    ok = passes(_map(definition, test, ref), EPS)
    assert ok.tolist() == [[False, True], [True, False]]


def test_unknown_definition_and_shape_mismatch_are_explained():
    ref = np.ones((2, 2, 3))
    with pytest.raises(ValueError, match="unknown bias definition"):
        bias_map("nope", ref, ref, 0.01)
    with pytest.raises(ValueError, match="does not match"):
        bias_map("relative-mse", ref, np.ones((2, 3, 3)), 0.01)
    with pytest.raises(ValueError, match="variance shape"):
        bias_map("authors", ref, ref, 0.01, v_variance=np.ones((3, 2, 3)))
