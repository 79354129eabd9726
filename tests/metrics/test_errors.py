"""Properties of MSE / MRSE / rBias^2 / rVar, the reference floor, per-cache statistics and
their non-finite accounting; the statistical claims are checked on synthetic renders of
known bias and variance."""

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
    per_cache_bias_variance,
    relative_squared_error_map,
)
from metrics.statistics import RunningMoments

FAST = settings(max_examples=60, deadline=None)

shapes = st.tuples(st.integers(1, 6), st.integers(1, 6), st.just(3))
# No subnormals: the scaling identities below hold where scaling by a power of two is
# exact, which a float32 below 1.2e-38 is not (2^-4 x 1.4e-45 underflows to 0).
values = st.floats(-50.0, 50.0, width=32, allow_nan=False, allow_infinity=False,
                   allow_subnormal=False)
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
    assert set(result) == {"mse", "mrse", "ref_floor", "mrse_corrected", "ref_floor_ratio_mrse",
                           "warnings", "flip_hdr", "flip_ldr", "flip_exposures",
                           "nonfinite_pixels", "ref_nonfinite_pixels", "finite", "error_maps"}
    assert result["error_maps"]["relative_squared_error"].shape == (16, 16)
    assert result["warnings"] == [] and result["ref_floor"] is None
    assert all(type(result[k]) in (float, int, bool, type(None))
               for k in result if k not in ("error_maps", "warnings"))


# ---- rBias^2 / rVar ----------------------------------------------------------


@FAST
@given(st.integers(2, 5), shapes, st.data())
def test_identity_check_of_the_implementation_mean_mrse_decomposes(k, shape, data):
    # An identity of the implementation, not evidence that the estimates are right
    # (that is tested on synthetic renders below): per pixel,
    # mean_k (X_k - R)^2 = (M - R)^2 + (K-1)/K S^2, so the mean MRSE over seeds is
    # rbias2_raw + (K-1)/K rvar = rbias2 + rvar + ref_floor for any input.
    renders = data.draw(arrays(np.float32, (k, *shape), elements=values))
    ref = data.draw(arrays(np.float32, shape, elements=values))
    ref_variance = data.draw(arrays(np.float32, shape, elements=st.floats(0.0, 4.0, width=32)))
    result = bias_variance(renders, ref, ref_variance=ref_variance)
    assert result["k"] == k
    scale = max(result["mrse_mean"], 1e-300)
    assert math.isclose(result["mrse_mean"],
                        result["rbias2_raw"] + (k - 1) / k * result["rvar"],
                        rel_tol=1e-9, abs_tol=1e-12 * scale)
    assert math.isclose(result["mrse_corrected"], result["rbias2"] + result["rvar"],
                        rel_tol=1e-9, abs_tol=1e-9 * (scale + result["ref_floor"]))
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


def test_expectations_over_repetitions_are_the_true_bias_and_variance():
    # E[rbias2] = b^2, E[rvar] = sigma^2 and E[MRSE] = b^2 + sigma^2 (relative, weighted),
    # checked on the mean over many independent synthetic experiments.
    rng = np.random.default_rng(21)
    eps, k, sigma, reps = 0.01, 4, 0.3, 300
    ref = rng.uniform(0.05, 2.0, (6, 6, 3))
    bias = np.full(ref.shape, 0.1)
    w = 1.0 / (ref * ref + eps)
    truth = {"rbias2": float(np.mean((bias * ref) ** 2 * w)),
             "rvar": float(np.mean((sigma * ref) ** 2 * w))}
    truth["mrse_mean"] = truth["rbias2"] + truth["rvar"]
    samples = {name: [] for name in truth}
    for _ in range(reps):
        result = bias_variance(_synthetic_renders(rng, ref, bias, sigma, k), ref, eps)
        for name in truth:
            samples[name].append(result[name])
    for name, expected in truth.items():
        mean, se = _mean_and_stderr(np.array(samples[name]))
        assert abs(mean - expected) < 4 * se, f"{name}: {mean:.5g} +- {se:.2g} vs {expected:.5g}"


# ---- The reference's own noise -------------------------------------------------------


def _noisy_reference(rng: np.random.Generator, truth: np.ndarray,
                     relative_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """A reference = truth + noise, with its (known) variance image."""
    variance = (relative_sigma * truth) ** 2
    return truth + np.sqrt(variance) * rng.standard_normal(truth.shape), variance


def test_reference_floor_is_subtracted_from_rbias2_and_mrse():
    rng = np.random.default_rng(8)
    eps, k, sigma = 0.01, 8, 0.3
    truth = rng.uniform(0.2, 2.0, (32, 32, 3))
    ref, ref_variance = _noisy_reference(rng, truth, 0.05)
    renders = _synthetic_renders(rng, truth, np.zeros_like(truth), sigma, k)
    result = bias_variance(renders, ref, eps, ref_variance=ref_variance)

    w = 1.0 / (ref * ref + eps)
    m, s2 = renders.mean(axis=0), renders.var(axis=0, ddof=1)
    _, se = _mean_and_stderr(((m - ref) ** 2 - s2 / k - ref_variance) * w)
    floor = float(np.mean(ref_variance * w))
    assert result["ref_floor"] == pytest.approx(floor, rel=1e-12)
    # Unbiased renders: corrected rBias^2 is 0 within its standard error, while the
    # term left after the render-noise floor alone is the reference floor.
    assert abs(result["rbias2"]) < 3 * se
    assert result["rbias2_raw"] - result["noise_floor"] == pytest.approx(floor, abs=3 * se)
    assert floor > 5 * se
    assert result["mrse_corrected"] == pytest.approx(result["mrse_mean"] - floor, rel=1e-12)
    assert result["ref_floor_ratio_mrse"] == pytest.approx(floor / result["mrse_corrected"])
    # rBias^2 is ~0, so the floor dominates it: warned. MRSE is ~30x the floor: not warned.
    assert len(result["warnings"]) == 1 and "rbias2" in result["warnings"][0]
    assert result["ref_floor_ratio_rbias2"] > 0.1


def test_reference_floor_warnings_follow_the_ten_percent_rule():
    rng = np.random.default_rng(9)
    truth = rng.uniform(0.2, 2.0, (16, 16, 3))
    renders = _synthetic_renders(rng, truth, np.full(truth.shape, 0.2), 0.1, 4)
    for relative_sigma, warned in ((0.01, False), (0.12, True)):
        ref, ref_variance = _noisy_reference(rng, truth, relative_sigma)
        result = bias_variance(renders, ref, ref_variance=ref_variance)
        ratio = result["ref_floor_ratio_rbias2"]
        assert (ratio > 0.1) is warned, ratio
        assert any("rbias2" in text for text in result["warnings"]) is warned

    single = image_metrics(truth * 1.01, truth, with_flip=False,
                           ref_variance=np.full(truth.shape, 1e-3))
    assert single["mrse_corrected"] == pytest.approx(single["mrse"] - single["ref_floor"])
    assert single["ref_floor_ratio_mrse"] > 0.1  # floor / |MRSE - floor|
    assert single["warnings"] and "mrse" in single["warnings"][0]


def test_reference_variance_must_match_and_be_non_negative():
    ref = np.ones((4, 4, 3))
    with pytest.raises(MetricError, match="variance image shape"):
        image_metrics(ref, ref, with_flip=False, ref_variance=np.ones((4, 5, 3)))
    with pytest.raises(MetricError, match="negative"):
        bias_variance(np.stack([ref, ref]), ref, ref_variance=-ref)
    variance = np.zeros_like(ref)
    variance[1, 2, 0] = math.inf
    result = image_metrics(ref, ref, with_flip=False, ref_variance=variance)
    assert result["ref_nonfinite_pixels"] == 1 and result["finite"] is False


# ---- Per-cache rBias^2 / rVar ----------------------------------------------------------


def _cache_estimates(rng: np.random.Generator, truth: np.ndarray, biases: list[float],
                     sigma: float, frames: int):
    """One MeanEstimate per cache from ``frames`` frames X = T (1 + b_k) + sigma T N."""
    estimates = []
    for b in biases:
        moments = RunningMoments()
        for frame in _synthetic_renders(rng, truth, np.full(truth.shape, b), sigma, frames):
            moments.add(frame)
        estimates.append(moments.estimate())
    return estimates


def test_per_cache_statistics_match_a_known_bias_and_variance():
    rng = np.random.default_rng(30)
    eps, sigma, frames, b = 0.01, 0.4, 16, 0.1
    truth = rng.uniform(0.2, 2.0, (24, 24, 3))
    ref, ref_variance = _noisy_reference(rng, truth, 0.02)
    caches = _cache_estimates(rng, truth, [b, b, b], sigma, frames)
    result = per_cache_bias_variance(caches, ref, eps, ref_variance=ref_variance)

    w = 1.0 / (ref * ref + eps)
    true_rbias2 = float(np.mean((b * truth) ** 2 * w))
    true_rvar = float(np.mean((sigma * truth) ** 2 * w))
    assert result["per_cache_frames"] == frames and result["per_cache_excluded_pixels"] == 0
    for c, rbias2, rvar in zip(caches, result["rbias2_per_cache"], result["rvar_per_cache"],
                               strict=True):
        s2 = c.variance_of_mean * frames
        _, se_bias = _mean_and_stderr(((c.mean - ref) ** 2 - s2 / frames - ref_variance) * w)
        _, se_var = _mean_and_stderr(s2 * w)
        assert abs(rbias2 - true_rbias2) < 4 * se_bias
        assert abs(rvar - true_rvar) < 4 * se_var
    assert result["rbias2_per_cache_mean"] == pytest.approx(np.mean(result["rbias2_per_cache"]))
    assert result["rbias2_per_cache_min"] <= result["rbias2_per_cache_mean"]
    assert result["rbias2_per_cache_std"] == pytest.approx(
        np.std(result["rbias2_per_cache"], ddof=1))


def test_opposite_cache_biases_cancel_when_pooled_but_not_per_cache():
    rng = np.random.default_rng(31)
    eps, sigma, frames, b = 0.01, 0.3, 16, 0.15
    truth = rng.uniform(0.2, 2.0, (24, 24, 3))
    caches = _cache_estimates(rng, truth, [b, -b] * 4, sigma, frames)
    per_cache = per_cache_bias_variance(caches, truth, eps)
    pooled = bias_variance([c.mean for c in caches], truth, eps)

    true_rbias2 = float(np.mean((b * truth) ** 2 / (truth * truth + eps)))
    assert per_cache["rbias2_per_cache_min"] > 0.8 * true_rbias2
    assert per_cache["rbias2_per_cache_mean"] == pytest.approx(true_rbias2, rel=0.1)
    # Pooled, the bias looks like variance between seeds: about -b^2 / (K - 1), not b^2.
    assert abs(pooled["rbias2"]) < 0.25 * true_rbias2


def test_per_cache_statistics_need_two_frames_and_equal_counts():
    ref = np.ones((4, 4, 3))
    one = RunningMoments()
    one.add(ref)
    with pytest.raises(MetricError, match="2 images"):
        one.estimate()
    rng = np.random.default_rng(0)
    two, three = (_cache_estimates(rng, ref, [0.0], 0.1, n)[0] for n in (2, 3))
    with pytest.raises(MetricError, match="different frame counts"):
        per_cache_bias_variance([two, three], ref)
    nan_cache = _cache_estimates(rng, ref, [0.0], 0.1, 2)[0]
    nan_cache.mean[0, 0, 0] = math.nan
    result = per_cache_bias_variance([two, nan_cache], ref)
    assert result["per_cache_excluded_pixels"] == 1 and result["rbias2_per_cache_std"] is not None
    assert per_cache_bias_variance([two], ref)["rbias2_per_cache_std"] is None


# ---- Efficiency --------------------------------------------------------------


def test_efficiency_is_inverse_mrse_times_time():
    assert efficiency(0.5, 0.02) == pytest.approx(100.0)


@pytest.mark.parametrize("bad", [(0.0, 1.0), (1.0, 0.0), (math.nan, 1.0), (None, 1.0)])
def test_efficiency_rejects_degenerate_inputs(bad):
    with pytest.raises(MetricError):
        efficiency(*bad)


def test_a_negative_corrected_bias_is_reported_below_the_noise_floor_by_magnitude():
    """Renders whose mean is the reference exactly: rBias² less the noise floors is
    negative; the warning speaks of its magnitude, not of a percentage of a negative
    number, and the result row lists it as below the noise floor."""
    ref = np.full((4, 4, 3), 0.5)
    renders = np.stack([ref * 0.9, ref, ref * 1.1])
    result = bias_variance(renders, ref, ref_variance=np.full_like(ref, 0.01))
    assert result["rbias2"] < 0
    (warning,) = [w for w in result["warnings"] if "rbias2" in w]
    assert f"magnitude of rbias2 ({abs(result['rbias2']):.3g}" in warning
    assert "below the noise floors" in warning and "-" not in warning.split("(")[1]
    from metrics.registry import row_values

    assert row_values(result)["below_noise_floor"] == ["rbias2"]
