"""PassAccumulator, the Šidák-corrected z-test, the aggregate block test, the image-mean
test, Student-t intervals and Welch's two-sample t-test."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from metrics.checks import MetricError
from metrics.statistics import (
    PassAccumulator,
    RunningMoments,
    aggregate_test,
    agreement_test,
    image_mean_test,
    interval_or_reason,
    mean_confidence_interval,
    positive_mean_interval,
    sidak_alpha,
    welch_interval,
    welch_test,
    z_test,
)

ROOT = Path(__file__).resolve().parents[2]

# ---- Welch's t-test ---------------------------------------------------------------

def test_welch_test_by_hand():
    """t = (mean_a - mean_b) / sqrt(s_a^2 / n_a + s_b^2 / n_b) with the
    Welch-Satterthwaite degrees of freedom, computed here from the formulas."""
    a, b = [1.0, 2.0, 3.0, 4.0], [2.0, 4.0, 6.0]
    va, vb = np.var(a, ddof=1) / len(a), np.var(b, ddof=1) / len(b)
    t = (np.mean(a) - np.mean(b)) / math.sqrt(va + vb)
    dof = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
    result = welch_test(a, b)
    assert result.statistic == pytest.approx(t)
    assert result.pvalue == pytest.approx(2.0 * stats.t.sf(abs(t), dof))
    assert welch_test(a, b, alternative="less").pvalue == pytest.approx(stats.t.cdf(t, dof))
    assert welch_test(a, b, alternative="greater").pvalue == pytest.approx(stats.t.sf(t, dof))
    low, high = welch_interval(a, b, 0.95)
    half = stats.t.ppf(0.975, dof) * math.sqrt(va + vb)
    assert (low, high) == pytest.approx((t * math.sqrt(va + vb) - half,
                                         t * math.sqrt(va + vb) + half))


@pytest.mark.parametrize("alternative", ["two-sided", "greater", "less"])
def test_welch_test_from_summaries_is_scipys_test_on_the_samples(alternative):
    """The test from means, deviations and sizes gives ttest_ind's statistic and p-value
    on random samples of unequal sizes and spreads, and on constant samples."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        a = rng.normal(0.0, rng.uniform(0.1, 2.0), rng.integers(2, 12))
        b = rng.normal(0.3, rng.uniform(0.1, 2.0), rng.integers(2, 12))
        ours = welch_test(a, b, alternative)
        scipy_result = stats.ttest_ind(a, b, equal_var=False, alternative=alternative)
        assert ours.statistic == pytest.approx(scipy_result.statistic, rel=1e-12)
        assert ours.pvalue == pytest.approx(scipy_result.pvalue, rel=1e-9, abs=1e-15)
    step = welch_test([1.0, 1.0, 1.0], [2.0, 2.0], alternative)
    assert step.statistic == -math.inf


def test_welch_test_is_the_only_unequal_variance_t_test():
    """The run comparison, the CI gate and the metric history use welch_test; no other
    module calls SciPy's unequal-variance t-test itself."""
    callers = sorted(str(path.relative_to(ROOT))
                     for package in ("service", "jobs", "renderers", "metrics")
                     for path in (ROOT / package).rglob("*.py")
                     if "equal_var" in path.read_text() and path.name != "statistics.py")
    assert callers == []
    users = {path.name for path in (ROOT / "jobs").rglob("*.py")
             if "welch_test(" in path.read_text() or "welch_interval(" in path.read_text()}
    assert users >= {"comparison.py", "ci_stats.py", "history.py"}


# ---- Student-t confidence interval -----------------------------------------------

def test_mean_confidence_interval_by_hand():
    mean, lo, hi = mean_confidence_interval([1.0, 2.0, 3.0, 4.0, 5.0])
    half = 2.776445105 * math.sqrt(2.5) / math.sqrt(5)
    assert mean == 3.0
    assert (lo, hi) == pytest.approx((3.0 - half, 3.0 + half), rel=1e-8)


def test_mean_confidence_interval_matches_t_tables():
    # Two-sided 95 % critical values from standard t tables, for n = df + 1 values.
    for df, critical in ((1, 12.706204736), (4, 2.776445105), (29, 2.045229642)):
        values = np.arange(df + 1, dtype=np.float64)
        mean, lo, hi = mean_confidence_interval(values)
        half = critical * values.std(ddof=1) / math.sqrt(values.size)
        assert (lo, hi) == pytest.approx((mean - half, mean + half), rel=1e-8)


def test_mean_confidence_interval_covers_the_mean_at_its_level():
    rng = np.random.default_rng(4)
    covered = sum(lo <= 0.0 <= hi
                  for _, lo, hi in (mean_confidence_interval(rng.standard_normal(4), 0.9)
                                    for _ in range(2000)))
    assert covered / 2000 == pytest.approx(0.9, abs=3 * math.sqrt(0.09 / 2000))


def test_mean_confidence_interval_rejects_too_few_or_nonfinite_values():
    with pytest.raises(MetricError):
        mean_confidence_interval([1.0])
    with pytest.raises(MetricError):
        mean_confidence_interval([1.0, math.nan])


# ---- PassAccumulator -----------------------------------------------------------


def _passes(rng: np.random.Generator, n: int, shape=(5, 4, 3), loc=1.0, scale=0.3):
    return [rng.normal(loc, scale, shape) for _ in range(n)]


@pytest.mark.parametrize("n", [2, 3, 7, 10])
def test_accumulator_matches_numpy(n):
    passes = _passes(np.random.default_rng(n), n)
    acc = PassAccumulator()
    for image in passes:
        acc.add(image)
    stack = np.stack(passes)
    assert acc.count == n
    np.testing.assert_allclose(acc.mean, stack.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(acc.variance, stack.var(axis=0, ddof=1), rtol=1e-10)
    np.testing.assert_allclose(acc.variance_of_mean, stack.var(axis=0, ddof=1) / n, rtol=1e-10)
    half_a, half_b = acc.split_halves()
    np.testing.assert_allclose(half_a, stack[0::2].mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(half_b, stack[1::2].mean(axis=0), rtol=1e-12)


def test_accumulator_is_stable_with_a_large_offset():
    # Naive sum-of-squares variance loses everything here; Welford does not.
    passes = _passes(np.random.default_rng(0), 50, loc=1e8, scale=1e-2)
    acc = PassAccumulator()
    for image in passes:
        acc.add(image)
    np.testing.assert_allclose(acc.variance, np.stack(passes).var(axis=0, ddof=1), rtol=1e-5)


def test_half_estimates_and_relative_stderr():
    passes = _passes(np.random.default_rng(1), 9)
    acc = PassAccumulator()
    for image in passes:
        acc.add(image)
    est_a, est_b = acc.half_estimates()
    evens, odds = np.stack(passes[0::2]), np.stack(passes[1::2])
    assert (est_a.count, est_b.count) == (5, 4)
    np.testing.assert_allclose(est_a.variance_of_mean, evens.var(axis=0, ddof=1) / 5, rtol=1e-10)
    np.testing.assert_allclose(est_b.variance_of_mean, odds.var(axis=0, ddof=1) / 4, rtol=1e-10)
    expected = math.sqrt(np.mean(acc.variance_of_mean / (acc.mean**2 + 0.01)))
    assert acc.relative_stderr() == pytest.approx(expected, rel=1e-12)
    assert acc.estimate().count == 9


def test_accumulator_refuses_bad_input():
    acc = PassAccumulator()
    with pytest.raises(MetricError):
        _ = acc.mean
    acc.add(np.ones((2, 2, 3)))
    with pytest.raises(MetricError, match="2 passes"):
        _ = acc.variance
    with pytest.raises(MetricError, match="shape"):
        acc.add(np.ones((2, 3, 3)))
    bad = np.ones((2, 2, 3))
    bad[0, 0, 0] = math.nan
    with pytest.raises(MetricError, match="non-finite"):
        acc.add(bad)
    assert acc.count == 1  # the rejected pass left no trace


def test_accumulator_returns_copies():
    acc = PassAccumulator()
    acc.add(np.zeros((1, 1, 3)))
    acc.mean[...] = 5.0
    assert acc.mean.max() == 0.0


# ---- Šidák correction -------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 10, 3 * 64 * 64, 3 * 1024 * 1024])
def test_sidak_alpha(n):
    per_test = sidak_alpha(0.01, n)
    # Family-wise level of n independent tests at the per-test level is alpha again.
    assert -math.expm1(n * math.log1p(-per_test)) == pytest.approx(0.01, rel=1e-12)
    if n <= 10:
        assert per_test == pytest.approx(1 - (1 - 0.01) ** (1 / n), rel=1e-12)
    assert per_test <= 0.01 / n * 1.01  # close to (and never looser than ~) Bonferroni


# ---- z-test -----------------------------------------------------------------------


def _accumulate(rng: np.random.Generator, n: int, mean: np.ndarray, sigma: float):
    acc = PassAccumulator()
    for _ in range(n):
        acc.add(mean + sigma * rng.standard_normal(mean.shape))
    return acc.estimate()


def test_z_test_passes_for_samples_of_one_distribution():
    truth = np.random.default_rng(100).uniform(0.2, 2.0, (12, 12, 3))
    outcomes = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        a = _accumulate(rng, 200, truth, 0.5)
        b = _accumulate(rng, 200, truth, 0.5)
        result = z_test(a.mean, a.variance_of_mean, b.mean, b.variance_of_mean)
        assert result.n_tested == truth.size
        assert result.alpha_corrected == pytest.approx(sidak_alpha(0.01, truth.size))
        outcomes.append(result.passed)
    # Family-wise false-failure rate is 1 %: expect ~0.2 failures in 20.
    assert sum(outcomes) >= 18


def test_z_test_detects_a_two_percent_shift_with_enough_samples():
    truth = np.random.default_rng(5).uniform(0.5, 1.0, (8, 8, 3))
    rng = np.random.default_rng(6)
    sigma = 0.1 * truth.mean()
    a = _accumulate(rng, 2000, truth, sigma)
    b = _accumulate(rng, 2000, truth * 1.02, sigma)
    result = z_test(a.mean, a.variance_of_mean, b.mean, b.variance_of_mean)
    assert not result.passed
    assert result.n_failed > truth.size // 2
    assert "FAILED" in result.summary()
    # With few samples the same shift hides in the noise: power needs samples.
    few_a = _accumulate(rng, 20, truth, sigma)
    few_b = _accumulate(rng, 20, truth * 1.02, sigma)
    assert z_test(few_a.mean, few_a.variance_of_mean, few_b.mean, few_b.variance_of_mean).passed


def test_z_test_p_values_are_uniform_under_the_null():
    rng = np.random.default_rng(11)
    n = 30000
    var_a, var_b = rng.uniform(0.1, 2.0, n), rng.uniform(0.1, 2.0, n)
    a = rng.normal(0.0, np.sqrt(var_a))
    b = rng.normal(0.0, np.sqrt(var_b))
    p = z_test(a, var_a, b, var_b).p_values
    for level in (0.01, 0.1, 0.5):
        assert np.mean(p < level) == pytest.approx(level, abs=4 * math.sqrt(level / n) + 1e-3)


def test_z_test_single_value_and_degenerate_variances():
    result = z_test(np.array([1.0]), np.array([0.5]), np.array([0.0]), np.array([0.5]))
    assert result.p_values[0] == pytest.approx(math.erfc(1 / math.sqrt(2)))  # z = 1
    assert result.alpha_corrected == pytest.approx(0.01)

    equal = z_test(np.array([2.0, 3.0]), 0.0, np.array([2.0, 3.0]), 0.0)
    assert equal.passed and equal.n_failed == 0 and np.all(equal.p_values == 1.0)

    differ = z_test(np.array([2.0, 3.0]), 0.0, np.array([2.0, 3.5]), 0.0)
    assert not differ.passed and differ.n_failed == 1
    assert differ.worst_index == (1,) and differ.min_p_value == 0.0


def test_z_test_fails_on_nonfinite_and_rejects_negative_variance():
    a = np.array([[1.0, math.nan]])
    result = z_test(a, 0.1, np.array([[1.0, 1.0]]), 0.1)
    assert not result.passed and result.n_nonfinite == 1 and result.worst_index == (0, 1)
    assert "non-finite" in result.summary()
    with pytest.raises(MetricError, match="variances"):
        z_test(np.ones(2), -1.0, np.ones(2), 1.0)
    with pytest.raises(MetricError, match="shapes"):
        z_test(np.ones(2), 1.0, np.ones(3), 1.0)


def test_z_test_summary_when_passing():
    result = z_test(np.zeros((2, 2)), 1.0, np.zeros((2, 2)), 1.0)
    assert result.passed
    assert result.summary().startswith("z-test passed: 0 of 4 pixel-channels")


def test_running_moments_match_numpy_and_propagate_nan():
    frames = _passes(np.random.default_rng(2), 6)
    moments = RunningMoments()
    for frame in frames:
        moments.add(frame.astype(np.float32))
    estimate = moments.estimate()
    stack = np.stack(frames).astype(np.float32).astype(np.float64)
    assert estimate.count == 6 and estimate.mean.dtype == np.float64
    np.testing.assert_allclose(estimate.mean, stack.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(estimate.variance_of_mean, stack.var(axis=0, ddof=1) / 6,
                               rtol=1e-10)
    bad = frames[0].copy()
    bad[0, 0, 0] = math.nan
    moments.add(bad)
    assert np.isnan(moments.estimate().mean[0, 0, 0])
    assert np.isfinite(moments.estimate().mean[1:]).all()
    with pytest.raises(MetricError, match="at least 2"):
        single = RunningMoments()
        single.add(frames[0])
        single.estimate()


# ---- Aggregate block test ----------------------------------------------------------

TRUTH = np.random.default_rng(100).uniform(0.2, 2.0, (24, 24, 3))
SPP = 256                                # samples behind each synthetic mean
VAR_OF_MEAN = TRUTH**2 / SPP             # 1-spp relative standard deviation ~1


def _noisy_mean(rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    """A mean over SPP samples of an estimator of ``scale`` x TRUTH with known variance."""
    return scale * TRUTH + np.sqrt(VAR_OF_MEAN) * rng.standard_normal(TRUTH.shape)


def _binomial_bound(alpha: float, n: int) -> float:
    """alpha plus 3 binomial standard deviations of a rejection rate over n repetitions."""
    return alpha + 3 * math.sqrt(alpha * (1 - alpha) / n)


def test_aggregate_test_finds_a_two_percent_bias_the_per_pixel_test_misses():
    # Per pixel the 2 % bias is ~0.2 standard deviations; over 108 blocks of 16
    # pixels per channel the pooled mean statistic moves by ~5-9.
    outcomes = []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        ref, test = _noisy_mean(rng), _noisy_mean(rng, scale=1.02)
        result = agreement_test(test, VAR_OF_MEAN, ref, VAR_OF_MEAN)
        assert not result.aggregate.passed, result.summary()
        assert result.aggregate.n_blocks == 6 * 6 and result.aggregate.mean_z > 3.5
        assert not result.passed
        outcomes.append(result.per_pixel.passed)
    assert sum(outcomes) >= 9  # the per-pixel test alone lets it through


def test_aggregate_test_false_rejection_rate_under_the_null():
    reps, alpha = 400, 0.01
    rejected = 0
    for seed in range(reps):
        rng = np.random.default_rng(10_000 + seed)
        result = aggregate_test(_noisy_mean(rng), VAR_OF_MEAN, _noisy_mean(rng), VAR_OF_MEAN,
                                alpha=alpha)
        rejected += not result.passed
    assert rejected / reps <= _binomial_bound(alpha, reps), f"{rejected} of {reps} rejected"


def test_estimated_variances_need_their_degrees_of_freedom():
    # Six passes per side: the variance estimates have 5 d.o.f., and z-scores
    # built from them are heavy-tailed. Block 1 tests every pixel on its own estimates.
    reps, alpha, passes = 400, 0.01, 6
    rejected = {"dof": 0, "none": 0}
    for seed in range(reps):
        rng = np.random.default_rng(20_000 + seed)
        sides = []
        for _ in range(2):
            acc = PassAccumulator()
            for _ in range(passes):
                acc.add(TRUTH + 0.5 * TRUTH * rng.standard_normal(TRUTH.shape))
            sides.append(acc.estimate())
        a, b = sides
        for label, dof in (("dof", passes - 1), ("none", None)):
            result = aggregate_test(a.mean, a.variance_of_mean, b.mean, b.variance_of_mean,
                                    dof=dof, block=1, alpha=alpha)
            rejected[label] += not result.passed
    rates = {label: count / reps for label, count in rejected.items()}
    message = f"rejection rates with dof={passes - 1} and with dof=None: {rates}"
    assert rates["dof"] <= _binomial_bound(alpha, reps), message
    assert rates["none"] > 3 * _binomial_bound(alpha, reps), message


# ---- Image-mean test (correlated pixels) -------------------------------------------

SEEDS = 4


def _correlated_seeds(rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    """SEEDS renders whose pixels share most of their noise, as spatial reuse makes them:
    each pixel's error is 0.9 of one image-wide draw plus 0.1 of its own (per-pixel
    variance of each render VAR_OF_MEAN x SEEDS, so their mean has VAR_OF_MEAN)."""
    sd = np.sqrt(VAR_OF_MEAN * SEEDS)
    shared = rng.standard_normal((SEEDS, 1, 1, 1))
    own = rng.standard_normal((SEEDS, *TRUTH.shape))
    return scale * TRUTH + sd * (0.9 * shared + math.sqrt(1 - 0.81) * own)


def test_image_mean_test_holds_its_level_where_the_tile_test_does_not():
    """Correlated pixels: the tile test, summing pixel variances as if independent,
    rejects correct renders most of the time (measured 342 of 400); the image-mean
    test at its level (2 of 400)."""
    reps, alpha = 400, 0.01
    rejected = {"tiles": 0, "image mean": 0}
    for seed in range(reps):
        rng = np.random.default_rng(30_000 + seed)
        seeds, ref = _correlated_seeds(rng), _noisy_mean(rng)
        mean, var = seeds.mean(axis=0), seeds.var(axis=0, ddof=1) / SEEDS
        rejected["tiles"] += not aggregate_test(mean, var, ref, VAR_OF_MEAN, dof=SEEDS - 1,
                                                alpha=alpha).passed
        rejected["image mean"] += not image_mean_test(seeds, ref, VAR_OF_MEAN, alpha).passed
    rates = {name: count / reps for name, count in rejected.items()}
    assert rates["image mean"] <= _binomial_bound(alpha, reps), rates
    assert rates["tiles"] > 0.3, rates


def test_image_mean_test_finds_a_bias_of_the_whole_image():
    """Power: a 15 % brighter image (~1.3 standard errors of one seed's image mean,
    whose error is mostly the shared draw; t ~5 over 16 seeds) is rejected in most
    trials (measured 95.5 % of 200), the same renders unbiased are not (0.5 %)."""
    outcomes = {1.0: 0, 1.15: 0}
    for seed in range(50):
        rng = np.random.default_rng(40_000 + seed)
        ref = _noisy_mean(rng)
        for scale in outcomes:
            seeds = np.concatenate([_correlated_seeds(rng, scale) for _ in range(4)])
            outcomes[scale] += not image_mean_test(seeds, ref, VAR_OF_MEAN).passed
    assert outcomes[1.15] >= 42 and outcomes[1.0] <= 2, outcomes


def test_image_mean_test_degenerate_inputs():
    images = np.ones((3, 4, 4, 3))
    assert image_mean_test(images, np.ones((4, 4, 3)), np.zeros((4, 4, 3))).passed
    assert not image_mean_test(images, 2 * np.ones((4, 4, 3)), np.zeros((4, 4, 3))).passed
    images[1, 0, 0, 0] = np.nan
    result = image_mean_test(images, np.ones((4, 4, 3)), np.zeros((4, 4, 3)))
    assert not result.passed and "FAILED" in result.summary()
    with pytest.raises(MetricError, match="seed images"):
        image_mean_test(np.ones((1, 4, 4, 3)), np.ones((4, 4, 3)), np.zeros((4, 4, 3)))


def test_aggregate_test_degenerate_inputs():
    image = np.ones((8, 8, 3))
    variance = np.ones_like(image)
    variance[:4, :4] = 0.0                        # one zero-variance tile per channel
    result = aggregate_test(image, variance, image, variance)
    assert result.passed and result.n_blocks == 3

    exact = aggregate_test(image, 0.0, image, 0.0)
    assert exact.passed and exact.n_blocks == 0

    shifted = image.copy()
    shifted[0, 0, 0] += 1.0
    assert not aggregate_test(shifted, 0.0, image, 0.0).passed

    nan = image.copy()
    nan[5, 5, 1] = math.nan
    failed = aggregate_test(nan, 1.0, image, 1.0)
    assert not failed.passed and failed.p_chi2 == 0.0 and "FAILED" in failed.summary()

    with pytest.raises(MetricError, match="smaller than one 4x4 block"):
        aggregate_test(np.ones((3, 8, 3)), 1.0, np.ones((3, 8, 3)), 1.0)
    with pytest.raises(MetricError, match="degrees of freedom"):
        aggregate_test(image, 1.0, image, 1.0, dof=0)


def test_z_test_with_estimated_variances_needs_their_degrees_of_freedom():
    """K = 8 normal passes per side, variances estimated from them: read as z the
    per-pixel test rejects equal means far above alpha; as a Student t with K - 1
    degrees of freedom it holds alpha, and it still rejects a shift of 3 sigma."""
    rng = np.random.default_rng(11)
    k, shape, repetitions = 8, (8, 8, 3), 200

    def moments(shift: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        passes = rng.normal(1.0 + shift, 1.0, (k, *shape))
        return passes.mean(axis=0), passes.var(axis=0, ddof=1) / k

    as_z = as_t = 0
    for _ in range(repetitions):
        a, b = moments(), moments()
        as_z += not z_test(*a, *b).passed
        as_t += not z_test(*a, *b, dof=k - 1).passed
    assert as_z / repetitions > 0.2
    assert as_t / repetitions <= 0.03
    shifted = z_test(*moments(shift=3.0), *moments(), dof=k - 1)
    assert not shifted.passed
    with pytest.raises(MetricError, match="degrees of freedom"):
        z_test(*moments(), *moments(), dof=0)


# ---- The interval of a non-negative mean (MRSE over seeds) ---------------------


def test_two_seeds_give_no_interval_and_say_why():
    ci, note = interval_or_reason([0.2, 0.4])
    assert ci is None and "2 seeds" in note and "3 or more" in note
    with pytest.raises(MetricError):
        positive_mean_interval([0.2, 0.4])


@pytest.mark.parametrize("values", [[1e-4, 2e-4, 6e-3], [1e-4] * 7 + [8e-3]])
def test_an_error_near_zero_keeps_its_interval_above_zero(values):
    """With K = 3 and K = 8 seeds of a quantity near zero the symmetric Student-t
    interval goes below zero; the log-scale interval holds the mean and stays above it."""
    mean, t_low, _ = mean_confidence_interval(values)
    assert t_low < 0
    (low, high), note = interval_or_reason(values)
    assert 0 < low <= mean <= high and "log scale" in note
    assert positive_mean_interval([0.0, 0.0, 0.0]) == (0.0, 0.0)


@pytest.mark.parametrize("k", [3, 8])
def test_the_positive_interval_covers_the_mean_at_its_level(k):
    """Skewed errors (scaled chi-square, 5 degrees of freedom, mean 1): the interval
    covers the true mean 95 % of the time, within three standard errors of 2000 draws."""
    rng = np.random.default_rng(7)
    covered = sum(low <= 1.0 <= high for low, high in (
        positive_mean_interval(rng.chisquare(5, k) / 5) for _ in range(2000)))
    assert covered / 2000 == pytest.approx(0.95, abs=3 * math.sqrt(0.95 * 0.05 / 2000))
