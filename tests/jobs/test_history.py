"""The step test of the CI history (jobs/ci/history.py), checked statistically:
its family-wise false-step rate on flat histories stays at alpha (and a detector without
Holm's correction, which the same check rejects, does not), it finds a planted step at
its commit, and the interval for the median covers at its stated level."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from jobs.ci.history import STEP_ALPHA, detect_steps, median_interval, welch_p

COMMITS, SEEDS, REPEATS = 10, 4, 400


def _histories(rng: np.random.Generator, step: float = 0.0, at: int = 5) -> list[np.ndarray]:
    """REPEATS histories of COMMITS x SEEDS values (unit noise, a step of ``step`` at ``at``)."""
    out = []
    for _ in range(REPEATS):
        values = rng.normal(1.0, 1.0, size=(COMMITS, SEEDS))
        values[at:] += step
        out.append(values)
    return out


def _any_step_rate(histories: list[np.ndarray], detector) -> float:
    compared = [False] + [True] * (COMMITS - 1)
    return float(np.mean([any(detector(list(h), compared)) for h in histories]))


def _holm_steps(samples, compared):
    return [step for _, _, step in detect_steps(samples, compared)]


def _uncorrected_steps(samples, compared):
    """Each pair at level alpha on its own: what the Holm adjustment is there to prevent."""
    return [bool(c) and welch_p(samples[i - 1], samples[i]) <= STEP_ALPHA
            for i, c in enumerate(compared)]


def _upper_bound(rate: float) -> float:
    """One-sided 99.9 % binomial bound on the observed rate of REPEATS trials at ``rate``."""
    return stats.binom.ppf(0.999, REPEATS, rate) / REPEATS


def test_flat_histories_show_a_false_step_at_most_at_alpha_and_uncorrected_tests_fail():
    histories = _histories(np.random.default_rng(1))
    assert _any_step_rate(histories, _holm_steps) <= _upper_bound(STEP_ALPHA)
    # The same check rejects testing each of the 9 pairs at alpha (FWER near 1 - 0.95^9).
    assert _any_step_rate(histories, _uncorrected_steps) > _upper_bound(STEP_ALPHA)


def test_a_planted_step_is_found_at_its_commit_and_nowhere_else():
    compared = [False] + [True] * (COMMITS - 1)
    exact = 0
    for h in _histories(np.random.default_rng(2), step=8.0, at=6):
        steps = _holm_steps(list(h), compared)
        exact += steps == [i == 6 for i in range(COMMITS)]
    assert exact / REPEATS >= 0.9


def test_a_break_is_never_tested():
    rng = np.random.default_rng(3)
    values = rng.normal(0.0, 0.01, size=(4, SEEDS))
    values[2:] += 1.0                       # a huge change, but across a break
    results = detect_steps(list(values), [False, True, False, True])
    assert [r[2] for r in results] == [False] * 4
    assert results[2][0] is None and results[2][1] is None


def test_constant_samples_are_a_step_only_when_they_differ():
    assert welch_p([1.0, 1.0], [1.0, 1.0]) == 1.0
    assert welch_p([1.0, 1.0], [2.0, 2.0]) == 0.0
    assert welch_p([1.0], [2.0, 2.0]) is None


def test_the_median_interval_covers_at_its_stated_level():
    rng = np.random.default_rng(4)
    true_median = math.log(2.0)             # of the unit exponential
    for n in (4, 8, 12):
        trials = 3000
        covered, level = 0, None
        for _ in range(trials):
            _, (lo, hi), level = median_interval(rng.exponential(size=n))
            covered += lo <= true_median <= hi
        assert n < 6 or level >= 0.95
        # Two-sided 99.9 % binomial acceptance region around the stated level.
        low, high = stats.binom.interval(0.999, trials, level)
        assert low <= covered <= high, (n, covered / trials, level)
