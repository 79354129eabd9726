"""Error against time (jobs/pareto/tradeoff.py) on synthetic data with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from jobs.pareto.tradeoff import (
    Sample,
    Speedup,
    baseline_curve,
    bootstrap_speedup,
    equal_error_seconds,
    pareto_front,
    speedup,
)

#: A synthetic baseline obeying the power law error = C * t^-A (PT: error ~ 1/spp, time ~ spp).
C, A = 2e-3, 0.8
SPP = (1, 2, 4, 8, 16)


def law_error(seconds: float) -> float:
    return C * seconds ** -A


def law_seconds(error: float) -> float:
    return (error / C) ** (-1 / A)


def baseline_points() -> tuple[list[float], list[float]]:
    seconds = [0.01 * n for n in SPP]
    return seconds, [law_error(t) for t in seconds]


def covers(result: Speedup, truth: float) -> bool:
    lo, hi = result.ci95
    return (lo is None or lo <= truth) and (hi is None or truth <= hi)


def test_the_front_keeps_exactly_the_points_nothing_beats_in_both():
    seconds = [1.0, 2.0, 3.0, 2.5, 1.0, None, 4.0]
    errors = [5.0, 3.0, 3.5, 1.0, 6.0, 0.1, 1.0]
    #          on    on    dominated by (2,3)   on   dominated by (1,5)   no time   (2.5,1) beats it
    assert pareto_front(seconds, errors) == [True, True, False, True, False, False, False]
    assert pareto_front([1.0, 1.0], [2.0, 2.0]) == [True, True]    # ties dominate neither
    assert pareto_front([1.0, float("nan")], [1.0, 0.5]) == [True, False]


def test_a_power_law_is_interpolated_exactly_in_log_log():
    curve = baseline_curve(*baseline_points())
    for error in (law_error(0.013), law_error(0.05), law_error(0.1599)):
        seconds, placement = equal_error_seconds(curve, error)
        assert placement == "in"
        assert seconds == pytest.approx(law_seconds(error), rel=1e-9)


def test_the_speed_up_at_equal_error_is_the_baseline_time_over_the_method_time():
    curve = baseline_curve(*baseline_points())
    # A method reaching the baseline's error at 0.06 s in 0.015 s: 4x faster.
    result = speedup(curve, law_error(0.06), 0.015)
    assert result.relation == "=" and result.value == pytest.approx(4.0, rel=1e-9)
    assert result.text() == "4"


def test_a_planted_linear_interpolation_misses_the_known_answer():
    """The known-answer test can fail: interpolating in linear space is off by > 5 %."""
    seconds, errors = baseline_points()
    error = law_error(0.06)
    linear = np.interp(error, errors[::-1], seconds[::-1])
    assert abs(linear / law_seconds(error) - 1) > 0.05


def test_errors_outside_the_baseline_range_give_bounds_never_extrapolations():
    curve = baseline_curve(*baseline_points())
    better = speedup(curve, law_error(0.5), 0.02)    # below the baseline's smallest error
    assert better.relation == ">" and better.value == pytest.approx(0.16 / 0.02)
    assert better.text() == "> 8" and "below" in better.note
    worse = speedup(curve, law_error(0.001), 0.02)   # above its largest error
    assert worse.relation == "<" and worse.value == pytest.approx(0.01 / 0.02)
    assert worse.text() == "< 0.5" and "above" in worse.note
    missing = speedup(curve, float("nan"), 0.02)
    assert missing.relation == "n/a" and missing.value is None and missing.text() == "n/a"


def test_the_baseline_curve_drops_dominated_points_and_rejects_non_positive_values():
    curve = baseline_curve([0.01, 0.02, 0.03, 0.04], [1.0, 0.5, 0.6, 0.2])
    assert list(curve.seconds) == [0.01, 0.02, 0.04] and list(curve.errors) == [1.0, 0.5, 0.2]
    with pytest.raises(ValueError):
        baseline_curve([0.01, 0.02], [1.0, 0.0])


def _noisy(rng: np.random.Generator, seconds: float, seeds: int = 8,
           timings: int = 3) -> Sample:
    """A point on the power law: per-seed errors and timing samples with noise."""
    return Sample(errors=law_error(seconds) * rng.lognormal(0.0, 0.15, seeds),
                  seconds=seconds * rng.lognormal(0.0, 0.03, timings))


def test_the_bootstrap_interval_covers_the_true_speed_up():
    """Over 40 synthetic data sets (the method 3x faster than the baseline at equal error)
    the 95 % interval contains 3 in at least 85 % of them; a planted error (the method's
    time taken twice too large) makes the same check fail."""
    rng = np.random.default_rng(7)
    truth, hits, planted_hits = 3.0, 0, 0
    for _ in range(40):
        baseline = [_noisy(rng, 0.01 * n) for n in SPP]
        point = _noisy(rng, 0.06)
        point = Sample(point.errors, [t / truth for t in point.seconds])
        result = bootstrap_speedup(baseline, point, resamples=400, seed=int(rng.integers(1e9)))
        hits += covers(result, truth)
        planted = Sample(point.errors, [2 * t for t in point.seconds])
        planted_hits += covers(bootstrap_speedup(baseline, planted, resamples=400), truth)
    assert hits >= 34, hits
    assert planted_hits <= 4, planted_hits


def test_bootstrap_ends_outside_the_baseline_range_are_unbounded():
    rng = np.random.default_rng(3)
    baseline = [_noisy(rng, 0.01 * n) for n in SPP]
    # Right at the baseline's smallest error: some replicates fall below its range.
    edge = Sample(errors=[law_error(0.16)] * 8, seconds=[0.04] * 3)
    result = bootstrap_speedup(baseline, edge, resamples=400)
    assert result.ci95[1] is None and result.ci95[0] is not None
    far = bootstrap_speedup(baseline, Sample([law_error(1.0)] * 4, [0.04] * 3), resamples=200)
    assert far.relation == ">" and far.ci95 == [None, None]
