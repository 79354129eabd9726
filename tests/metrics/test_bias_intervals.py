"""Coverage of the rBias² and rVar intervals (metrics.bias_intervals) on synthetic renders
of known bias and variance, at K = 4 and K = 16 seeds, each check with a planted wrong
interval it rejects.

Coverage is counted over REPS independent repetitions and must lie within three binomial
standard errors of 95 % (a conservative interval: at least 95 % less three).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from metrics.bias_intervals import (
    bias_interval,
    jackknife_values,
    per_cache_headline,
    seed_gram,
)
from metrics.errors import bias_variance, per_cache_bias_variance
from metrics.statistics import MeanEstimate, RunningMoments

REPS = 400
BAND = 3 * math.sqrt(0.95 * 0.05 / REPS)    # 0.033
EPS = 0.01
SHAPE = (6, 6, 3)


def _cache_run(rng: np.random.Generator, truth: np.ndarray, k: int, shared: float,
               spread: float, sigma: float, frames: int) -> list[MeanEstimate]:
    """K caches, each with its own relative bias shared + spread z_k per pixel (z_k
    standard normal per pixel: a bias pattern of many independent modes), rendered in
    ``frames`` frames of relative noise ``sigma``."""
    caches = []
    for _ in range(k):
        biased = truth * (1.0 + shared + spread * rng.standard_normal(truth.shape))
        moments = RunningMoments()
        for _ in range(frames):
            moments.add(biased + sigma * truth * rng.standard_normal(truth.shape))
        caches.append(moments.estimate())
    return caches


def _coverage(covers, reps: int = REPS) -> float:
    return sum(bool(covers(i)) for i in range(reps)) / reps


@pytest.mark.parametrize("k", [4, 16])
def test_per_cache_rbias2_interval_covers_one_caches_squared_bias(k):
    """Caches biased by 2 % in common and 6 % each their own way (pooled, the own part
    cancels): the t interval over the K caches covers E[b_k^2] w at 95 %. Planted: the
    normal quantile instead of Student t at K = 4 covers ~86 %, the pooled interval
    (jackknife of the mean image) covers the pooled (E b)^2 w, far below."""
    rng = np.random.default_rng(100 + k)
    truth = rng.uniform(0.3, 1.5, SHAPE)
    shared, spread, sigma, frames = 0.02, 0.06, 0.2, 4
    w = 1.0 / (truth ** 2 + EPS)
    squared_bias = float(np.mean(truth ** 2 * (shared ** 2 + spread ** 2) * w))
    z = stats.norm.ppf(0.975)
    hits = {"t": 0, "z": 0, "pooled": 0}
    for _ in range(REPS):
        caches = _cache_run(rng, truth, k, shared, spread, sigma, frames)
        metrics = {**bias_variance([c.mean for c in caches], truth, EPS),
                   **per_cache_bias_variance(caches, truth, EPS)}
        headline = per_cache_headline(metrics)
        low, high = headline["rbias2_ci95"]
        hits["t"] += low <= squared_bias <= high
        values = np.asarray(headline["rbias2_seed_values"])
        half = z * values.std(ddof=1) / math.sqrt(k)
        hits["z"] += abs(values.mean() - squared_bias) <= half
        pooled_low, pooled_high = metrics["rbias2_ci95"]
        hits["pooled"] += pooled_low <= squared_bias <= pooled_high
    coverage = {name: count / REPS for name, count in hits.items()}
    assert abs(coverage["t"] - 0.95) <= BAND, coverage
    if k == 4:
        assert coverage["z"] < 0.95 - BAND, coverage
    assert coverage["pooled"] < 0.5, coverage


@pytest.mark.parametrize("k", [4, 16])
def test_pooled_intervals_cover_a_fixed_bias_and_the_variance(k):
    """A method without a cache (a fixed 10 % bias, 30 % noise per pixel, pixels
    independent): the jackknife intervals cover the true rBias² and rVar at least at
    95 % (the jackknife variance of a U-statistic is never too small in expectation,
    Efron & Stein 1981, so rBias²'s interval is conservative at K = 4). Planted: the
    spread of the leave-one-out estimates taken for that of the pseudo-values (K - 1
    times smaller) covers far too seldom."""
    rng = np.random.default_rng(200 + k)
    truth = rng.uniform(0.3, 1.5, SHAPE)
    bias, sigma = 0.1, 0.3
    w = 1.0 / (truth ** 2 + EPS)
    true_rbias2 = float(np.mean((bias * truth) ** 2 * w))
    true_rvar = float(np.mean((sigma * truth) ** 2 * w))
    t = stats.t.ppf(0.975, k - 1)
    hits = {"rbias2": 0, "rvar": 0, "leave-one-out spread": 0}
    for _ in range(REPS):
        renders = truth * (1 + bias + sigma * rng.standard_normal((k, *SHAPE)))
        result = bias_variance(renders, truth, EPS)
        low, high = result["rbias2_ci95"]
        hits["rbias2"] += low <= true_rbias2 <= high
        low, high = result["rvar_ci95"]
        hits["rvar"] += low <= true_rvar <= high
        pseudo = np.asarray(result["rbias2_seed_values"])
        leave_one_out = (k * result["rbias2"] - pseudo) / (k - 1)
        half = t * leave_one_out.std(ddof=1) / math.sqrt(k)
        hits["leave-one-out spread"] += abs(result["rbias2"] - true_rbias2) <= half
    coverage = {name: count / REPS for name, count in hits.items()}
    assert 0.95 - BAND <= coverage["rbias2"] <= 0.995, coverage
    assert abs(coverage["rvar"] - 0.95) <= BAND, coverage
    assert coverage["leave-one-out spread"] < 0.95 - BAND, coverage


def test_cache_methods_rvar_interval_holds_when_the_pixels_share_the_cache():
    """Each seed's render shares one error over 30 % of its variance across all pixels
    (what a cache does): the chi-square interval on K - 1 degrees of freedom covers rVar
    at least at 95 %; the jackknife one (planted: what a method without a cache gets)
    covers too seldom (~86 % at K = 4)."""
    rng = np.random.default_rng(300)
    k, sigma, shared = 4, 0.3, 0.3
    truth = rng.uniform(0.3, 1.5, SHAPE)
    true_rvar = float(np.mean((sigma * truth) ** 2 / (truth ** 2 + EPS)))
    hits = {"chi2": 0, "jackknife": 0}
    for _ in range(REPS):
        noise = (math.sqrt(shared) * rng.standard_normal((k, 1, 1, 1))
                 + math.sqrt(1 - shared) * rng.standard_normal((k, *SHAPE)))
        result = bias_variance(truth * (1 + sigma * noise), truth, EPS)
        low, high = result["rvar_ci95"]
        hits["jackknife"] += low <= true_rvar <= high
        low, high = per_cache_headline({**result, "rbias2_per_cache": [0.0] * k})["rvar_ci95"]
        hits["chi2"] += low <= true_rvar <= high
    coverage = {name: count / REPS for name, count in hits.items()}
    assert coverage["chi2"] >= 0.95 - BAND, coverage
    assert coverage["jackknife"] < 0.95 - BAND, coverage


def test_jackknife_values_are_the_delete_one_seed_pseudo_values():
    """Against leave-one-out estimates computed by bias_variance on K - 1 renders."""
    rng = np.random.default_rng(400)
    truth = rng.uniform(0.3, 1.5, SHAPE)
    renders = truth * (1.05 + 0.2 * rng.standard_normal((5, *SHAPE)))
    full = bias_variance(renders, truth, EPS)
    for i in range(5):
        rest = bias_variance(np.delete(renders, i, axis=0), truth, EPS)
        assert full["rbias2_seed_values"][i] == pytest.approx(
            5 * full["rbias2"] - 4 * rest["rbias2"])
        assert full["rvar_seed_values"][i] == pytest.approx(5 * full["rvar"] - 4 * rest["rvar"])
    errors = ((renders - truth) / np.sqrt(truth ** 2 + EPS)).reshape(5, -1)
    bias_values, _ = jackknife_values(seed_gram(errors))
    assert np.mean(bias_values) == pytest.approx(full["rbias2"])


def test_too_few_seeds_give_no_interval_and_say_why():
    ci, note = bias_interval([0.1, 0.2], "how")
    assert ci is None and "2 seeds" in note
    rng = np.random.default_rng(500)
    truth = rng.uniform(0.3, 1.5, SHAPE)
    result = bias_variance(truth * (1 + 0.1 * rng.standard_normal((2, *SHAPE))), truth, EPS)
    assert result["rbias2_ci95"] is None and "2 seeds" in result["rbias2_ci_note"]
    assert per_cache_headline({**result, "rbias2_per_cache": [0.1, 0.2]})["rbias2_ci95"] is None
