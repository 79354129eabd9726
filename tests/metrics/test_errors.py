"""Properties of MSE / MRSE / rBias^2 / rVar and their non-finite accounting."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from metrics.errors import (
    MetricError,
    bias_variance,
    count_nonfinite,
    efficiency,
    image_metrics,
    mrse,
    mse,
    relative_squared_error_map,
)

FAST = settings(max_examples=60, deadline=None)

shapes = st.tuples(st.integers(1, 6), st.integers(1, 6), st.just(3))
values = st.floats(-50.0, 50.0, width=32, allow_nan=False, allow_infinity=False)
eps_values = st.floats(1e-4, 10.0)


@st.composite
def image_pairs(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    shape = draw(shapes)
    test = draw(arrays(np.float32, shape, elements=values))
    ref = draw(arrays(np.float32, shape, elements=values))
    return test, ref


# ---- MSE / MRSE ------------------------------------------------------------


@FAST
@given(image_pairs(), eps_values)
def test_errors_are_non_negative(pair, eps):
    test, ref = pair
    assert mse(test, ref) >= 0.0
    assert mrse(test, ref, eps) >= 0.0


@FAST
@given(arrays(np.float32, shapes, elements=values), eps_values)
def test_error_of_reference_against_itself_is_zero(ref, eps):
    assert mse(ref, ref) == 0.0
    assert mrse(ref, ref, eps) == 0.0


@FAST
@given(image_pairs())
def test_mse_is_symmetric(pair):
    test, ref = pair
    assert mse(test, ref) == mse(ref, test)


@FAST
@given(image_pairs(), eps_values, st.integers(-4, 4))
def test_mrse_is_invariant_under_joint_scaling_with_eps(pair, eps, log2_scale):
    # MRSE(sX, sR, s^2 eps) = MRSE(X, R, eps): MRSE is unitless once eps scales too.
    test, ref = pair
    s = 2.0 ** log2_scale
    assert math.isclose(mrse(test * s, ref * s, eps * s * s), mrse(test, ref, eps),
                        rel_tol=1e-9, abs_tol=1e-300)
    assert math.isclose(mse(test * s, ref * s), s * s * mse(test, ref), rel_tol=1e-9)


@FAST
@given(image_pairs(), eps_values, eps_values)
def test_mrse_is_bounded_by_mse_over_eps_and_decreases_with_eps(pair, eps_a, eps_b):
    test, ref = pair
    small, large = sorted((eps_a, eps_b))
    assert mrse(test, ref, small) <= mse(test, ref) / small * (1 + 1e-12)
    assert mrse(test, ref, large) <= mrse(test, ref, small) * (1 + 1e-12)


@FAST
@given(image_pairs(), eps_values)
def test_error_map_averages_to_mrse(pair, eps):
    test, ref = pair
    error_map = relative_squared_error_map(test, ref, eps)
    assert error_map.shape == test.shape[:2]
    assert error_map.dtype == np.float32
    assert math.isclose(float(error_map.astype(np.float64).mean()), mrse(test, ref, eps),
                        rel_tol=1e-5, abs_tol=1e-30)


def test_mrse_matches_the_definition_on_a_hand_example():
    ref = np.array([[[1.0, 0.0, 2.0]]], np.float32)
    test = np.array([[[2.0, 0.1, 2.0]]], np.float32)
    expected = (1.0 / 1.01 + 0.01 / 0.01 + 0.0) / 3
    assert math.isclose(mrse(test, ref), expected, rel_tol=1e-6)
    assert math.isclose(mse(test, ref), (1.0 + 0.01) / 3, rel_tol=1e-6)


def test_shape_mismatch_names_both_shapes():
    with pytest.raises(MetricError, match=r"\(4, 4, 3\).*\(4, 5, 3\)"):
        mrse(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))
    with pytest.raises(MetricError):
        image_metrics(np.zeros((4, 4, 3)), np.zeros((5, 4, 3)), with_flip=False)


@pytest.mark.parametrize("eps", [0.0, -1.0, math.nan, math.inf])
def test_eps_must_be_positive(eps):
    with pytest.raises(MetricError, match="eps"):
        mrse(np.ones((2, 2, 3)), np.ones((2, 2, 3)), eps)


# ---- Non-finite pixels -----------------------------------------------------


@st.composite
def images_with_bad_pixels(draw: st.DrawFn):
    test, ref = draw(image_pairs())
    h, w, _ = test.shape
    bad = draw(arrays(np.bool_, (h, w)))
    channel = draw(st.integers(0, 2))
    value = draw(st.sampled_from([math.nan, math.inf, -math.inf]))
    test = test.copy()
    test[bad, channel] = value
    return test, ref, bad


@FAST
@given(images_with_bad_pixels())
def test_nonfinite_pixels_are_counted_and_excluded(case):
    test, ref, bad = case
    assert count_nonfinite(test) == int(bad.sum())
    result = image_metrics(test, ref, with_flip=False)
    assert result["nonfinite_pixels"] == int(bad.sum())
    assert result["ref_nonfinite_pixels"] == 0
    assert result["finite"] is (not bad.any())
    good = ~bad
    if good.any():
        # The averages are exactly those over the finite pixels only.
        expected = mrse(test[good][None], ref[good][None])
        assert math.isclose(result["mrse"], expected, rel_tol=1e-12, abs_tol=1e-300)
        assert math.isfinite(result["mse"])
    else:
        assert result["mrse"] is None and result["mse"] is None


def test_nonfinite_reference_pixels_fail_the_quality_flag():
    ref = np.ones((3, 3, 3), np.float32)
    ref[1, 1, 2] = math.nan
    result = image_metrics(ref.copy(), ref, with_flip=False)
    assert result["ref_nonfinite_pixels"] == 1
    assert result["nonfinite_pixels"] == 1  # the test image is the same array
    assert result["finite"] is False
    assert result["mrse"] == 0.0


def test_plain_mrse_does_not_hide_nans():
    test = np.ones((2, 2, 3), np.float32)
    test[0, 0, 0] = math.nan
    assert math.isnan(mrse(test, np.ones_like(test)))


def test_image_metrics_maps_and_json_ready_values():
    rng = np.random.default_rng(1)
    ref = rng.uniform(0.1, 2.0, (16, 16, 3)).astype(np.float32)
    test = ref * 1.1
    result = image_metrics(test, ref, with_flip=False, return_maps=True)
    assert set(result) == {"mse", "mrse", "flip_hdr", "flip_ldr", "flip_exposures",
                           "nonfinite_pixels", "ref_nonfinite_pixels", "finite", "error_maps"}
    assert result["error_maps"]["relative_squared_error"].shape == (16, 16)
    assert all(type(result[k]) in (float, int, bool, type(None))
               for k in result if k != "error_maps")


# ---- rBias^2 / rVar ----------------------------------------------------------


@FAST
@given(st.integers(2, 5), shapes, st.data())
def test_mean_mrse_equals_rbias2_plus_rvar_exactly(k, shape, data):
    renders = data.draw(arrays(np.float32, (k, *shape), elements=values))
    ref = data.draw(arrays(np.float32, shape, elements=values))
    result = bias_variance(renders, ref)
    assert result["k"] == k
    assert len(result["mrse_per_seed"]) == k
    scale = max(result["mrse_mean"], 1e-300)
    # mean_k MRSE_k = rbias2_raw + (K-1)/K rvar = rbias2 + rvar (algebra, see docstring)
    assert math.isclose(result["mrse_mean"],
                        result["rbias2_raw"] + (k - 1) / k * result["rvar"],
                        rel_tol=1e-9, abs_tol=1e-12 * scale)
    assert math.isclose(result["mrse_mean"], result["rbias2"] + result["rvar"],
                        rel_tol=1e-9, abs_tol=1e-12 * scale)
    assert math.isclose(result["noise_floor"], result["rvar"] / k, rel_tol=1e-12)
    assert result["rvar"] >= 0.0 and result["rbias2_raw"] >= 0.0
    lo, hi = result["mrse_ci95"]
    assert lo <= result["mrse_mean"] <= hi
    assert result["mrse_per_seed"] == pytest.approx(
        [mrse(renders[i], ref) for i in range(k)], rel=1e-12, abs=1e-300)


def _synthetic_renders(rng: np.random.Generator, ref: np.ndarray, relative_bias: np.ndarray,
                       relative_sigma: float, k: int) -> np.ndarray:
    """K 1-spp-like renders X = R (1 + b) + sigma R N(0, 1): known bias and variance."""
    noise = rng.standard_normal((k, *ref.shape))
    return ref * (1.0 + relative_bias) + relative_sigma * ref * noise


def _mean_and_stderr(terms: np.ndarray) -> tuple[float, float]:
    return float(terms.mean()), float(terms.std(ddof=1) / math.sqrt(terms.size))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bias_and_variance_recover_a_known_estimator(seed):
    rng = np.random.default_rng(seed)
    eps, k, sigma = 0.01, 16, 0.3
    ref = rng.uniform(0.02, 2.0, (48, 48, 3))
    bias = rng.uniform(0.0, 0.15, ref.shape)       # per-pixel relative bias
    renders = _synthetic_renders(rng, ref, bias, sigma, k)
    result = bias_variance(renders.astype(np.float32), ref.astype(np.float32), eps)

    w = 1.0 / (ref * ref + eps)
    true_rbias2 = float(np.mean((bias * ref) ** 2 * w))
    true_rvar = float(np.mean((sigma * ref) ** 2 * w))

    # Statistical tolerance: 5 standard errors of the per-element terms.
    m = renders.mean(axis=0)
    s2 = renders.var(axis=0, ddof=1)
    _, se_bias = _mean_and_stderr(((m - ref) ** 2 - s2 / k) * w)
    _, se_var = _mean_and_stderr(s2 * w)
    _, se_mrse = _mean_and_stderr((((renders - ref) ** 2).mean(axis=0)) * w)
    assert abs(result["rbias2"] - true_rbias2) < 5 * se_bias
    assert abs(result["rvar"] - true_rvar) < 5 * se_var
    # E[MRSE] of one render = true rBias^2 + true rVar
    assert abs(result["mrse_mean"] - (true_rbias2 + true_rvar)) < 5 * se_mrse
    # The raw term overestimates the bias by the noise floor; the corrected one does not.
    assert result["rbias2_raw"] - true_rbias2 > 5 * se_bias
    assert result["noise_floor"] == pytest.approx(true_rvar / k, rel=0.05)


def test_unbiased_estimator_has_rbias2_near_zero():
    rng = np.random.default_rng(7)
    ref = rng.uniform(0.1, 1.0, (32, 32, 3))
    renders = _synthetic_renders(rng, ref, np.zeros_like(ref), 0.5, 8)
    result = bias_variance(renders, ref)
    w = 1.0 / (ref * ref + 0.01)
    m, s2 = renders.mean(axis=0), renders.var(axis=0, ddof=1)
    _, se = _mean_and_stderr(((m - ref) ** 2 - s2 / 8) * w)
    assert abs(result["rbias2"]) < 5 * se
    assert result["rbias2_raw"] == pytest.approx(result["noise_floor"], rel=0.1)


def test_bias_variance_accepts_a_list_and_excludes_nonfinite_pixels():
    rng = np.random.default_rng(3)
    ref = rng.uniform(0.5, 1.0, (4, 4, 3)).astype(np.float32)
    renders = [ref + 0.1 * rng.standard_normal(ref.shape).astype(np.float32) for _ in range(3)]
    renders[1][2, 3, 0] = math.inf
    result = bias_variance(renders, ref)
    assert result["nonfinite_pixels"] == 1
    assert result["nonfinite_pixels_per_seed"] == [0, 1, 0]
    assert result["finite"] is False
    keep = np.ones((4, 4), bool)
    keep[2, 3] = False
    clean = bias_variance([x[keep][None] for x in renders], ref[keep][None])
    for key in ("rbias2", "rbias2_raw", "rvar", "mrse_mean"):
        assert result[key] == pytest.approx(clean[key], rel=1e-12)


def test_bias_variance_needs_two_renders_of_the_reference_shape():
    ref = np.ones((4, 4, 3), np.float32)
    with pytest.raises(MetricError, match="K >= 2"):
        bias_variance(ref[None], ref)
    with pytest.raises(MetricError, match="shape"):
        bias_variance(np.ones((2, 4, 5, 3)), ref)


def test_identical_renders_have_no_variance():
    ref = np.full((3, 3, 3), 0.5, np.float32)
    # 0.625 = 1.25 x 0.5 keeps every sum exact, so the variance is exactly 0.
    result = bias_variance(np.stack([ref * 1.25] * 4), ref)
    assert result["rvar"] == 0.0 and result["noise_floor"] == 0.0
    assert result["rbias2"] == pytest.approx(0.125**2 / (0.25 + 0.01))
    assert result["mrse_ci95"] == pytest.approx((result["mrse_mean"], result["mrse_mean"]))


# ---- Efficiency --------------------------------------------------------------


def test_efficiency_is_inverse_mrse_times_time():
    assert efficiency(0.5, 0.02) == pytest.approx(100.0)


@pytest.mark.parametrize("bad", [(0.0, 1.0), (1.0, 0.0), (math.nan, 1.0), (None, 1.0)])
def test_efficiency_rejects_degenerate_inputs(bad):
    with pytest.raises(MetricError):
        efficiency(*bad)
