"""PassAccumulator, the Šidák-corrected z-test and Student-t intervals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from metrics.checks import MetricError
from metrics.statistics import (
    PassAccumulator,
    mean_confidence_interval,
    sidak_alpha,
    student_t_cdf,
    student_t_quantile,
    z_test,
)

# ---- Student t ---------------------------------------------------------------

# Two-sided critical values from standard t tables.
T_TABLE = [
    (0.975, 1, 12.706204736),
    (0.975, 2, 4.302652730),
    (0.975, 5, 2.570581836),
    (0.975, 10, 2.228138852),
    (0.975, 30, 2.042272456),
    (0.975, 1000, 1.962339081),
    (0.995, 4, 4.604094871),
    (0.95, 7, 1.894578605),
]


@pytest.mark.parametrize(("q", "df", "expected"), T_TABLE)
def test_student_t_quantile_matches_tables(q, df, expected):
    assert student_t_quantile(q, df) == pytest.approx(expected, rel=1e-8)
    assert student_t_quantile(1 - q, df) == pytest.approx(-expected, rel=1e-8)
    assert student_t_cdf(expected, df) == pytest.approx(q, abs=1e-10)


def test_student_t_approaches_the_normal_distribution():
    assert student_t_cdf(1.0, 1e7) == pytest.approx(0.5 * math.erfc(-1 / math.sqrt(2)), abs=1e-7)
    assert student_t_cdf(0.0, 3) == 0.5


def test_mean_confidence_interval_by_hand():
    mean, lo, hi = mean_confidence_interval([1.0, 2.0, 3.0, 4.0, 5.0])
    half = 2.776445105 * math.sqrt(2.5) / math.sqrt(5)
    assert mean == 3.0
    assert (lo, hi) == pytest.approx((3.0 - half, 3.0 + half), rel=1e-8)


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
