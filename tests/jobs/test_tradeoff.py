"""Error against time (jobs/pareto/tradeoff.py) on synthetic data with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from jobs.pareto.tradeoff import (
    Sample,
    Speedup,
    bootstrap_speedup,
    envelope_seconds,
    equal_error_seconds,
    speedup,
)
from jobs.views.envelope import (
    Curve,
    baseline_curve,
    curve_error,
    envelope_error,
    envelope_pieces,
)
from jobs.views.front import pareto_front

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
    result = speedup({"PT": curve}, law_error(0.06), 0.015)
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
    better = speedup({"PT": curve}, law_error(0.5), 0.02)    # below the baseline's smallest error
    assert better.relation == ">" and better.value == pytest.approx(0.16 / 0.02)
    assert better.text() == "> 8" and "below" in better.note
    worse = speedup({"PT": curve}, law_error(0.001), 0.02)   # above its largest error
    assert worse.relation == "<" and worse.value == pytest.approx(0.01 / 0.02)
    assert worse.text() == "< 0.5" and "above" in worse.note
    missing = speedup({"PT": curve}, float("nan"), 0.02)
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
        result = bootstrap_speedup({"PT": baseline}, point, resamples=400,
                                   seed=int(rng.integers(1e9)))
        hits += covers(result, truth)
        planted = Sample(point.errors, [2 * t for t in point.seconds])
        planted_hits += covers(bootstrap_speedup({"PT": baseline}, planted, resamples=400),
                               truth)
    assert hits >= 34, hits
    assert planted_hits <= 4, planted_hits


def test_bootstrap_ends_outside_the_baseline_range_are_unbounded():
    rng = np.random.default_rng(3)
    baseline = [_noisy(rng, 0.01 * n) for n in SPP]
    # Right at the baseline's smallest error: some replicates fall below its range.
    edge = Sample(errors=[law_error(0.16)] * 8, seconds=[0.04] * 3)
    result = bootstrap_speedup({"PT": baseline}, edge, resamples=400)
    assert result.ci95[1] is None and result.ci95[0] is not None
    far = bootstrap_speedup({"PT": baseline}, Sample([law_error(1.0)] * 4, [0.04] * 3),
                            resamples=200)
    assert far.relation == ">" and far.ci95 == [None, None]


# ---- The lower envelope of several baseline curves (the strongest PT) ----

#: A second baseline, steeper (error ~ t^-1.5) and crossing the first at CROSS seconds:
#: worse below CROSS, better above it (a series better only at large times).
CROSS, STEEP = 0.05, 1.5


def steep_error(seconds: float) -> float:
    return law_error(CROSS) * (seconds / CROSS) ** -STEEP


def steep_seconds(error: float) -> float:
    return CROSS * (error / law_error(CROSS)) ** (-1 / STEEP)


def two_curves(steep_from: float = 0.01) -> dict[str, Curve]:
    """'flat': the power law at 0.01..0.16 s; 'steep' at steep_from * (1, 2, 4, 8, 16)."""
    return {"flat": baseline_curve(*baseline_points()),
            "steep": baseline_curve([steep_from * n for n in SPP],
                                    [steep_error(steep_from * n) for n in SPP])}


def test_the_envelope_picks_the_lower_curve_at_each_time():
    """The steep curve, better only above CROSS, is the envelope there and nowhere else;
    outside a curve's measured range only the other counts (never an extrapolation)."""
    curves = two_curves(steep_from=0.02)             # steep measured at 0.02..0.32 s
    for seconds, winner in ((0.012, "flat"), (0.03, "flat"), (0.049, "flat"),
                            (0.051, "steep"), (0.1, "steep"), (0.16, "steep"),
                            (0.25, "steep")):
        error, name = envelope_error(curves, seconds)
        assert name == winner, seconds
        assert error == pytest.approx(min(curve_error(c, seconds) for c in curves.values()
                                          if c.seconds[0] <= seconds <= c.seconds[-1]))
    # Neither curve alone is the envelope (a planted 'pick one series' would fail here).
    assert envelope_error(curves, 0.03)[0] < curve_error(curves["steep"], 0.03)
    assert envelope_error(curves, 0.1)[0] < curve_error(curves["flat"], 0.1)
    assert envelope_error(curves, 0.005) is None and envelope_error(curves, 0.5) is None
    pieces = envelope_pieces(curves)
    assert [p.series for p in pieces] == ["flat", "steep"]
    assert pieces[0].from_s == pytest.approx(0.01) and pieces[1].to_s == pytest.approx(0.32)
    assert pieces[0].to_s == pytest.approx(CROSS, rel=1e-9) == pieces[1].from_s


def test_a_gap_between_measured_ranges_lies_in_no_piece():
    curves = {"early": baseline_curve([0.01, 0.02], [law_error(0.01), law_error(0.02)]),
              "late": baseline_curve([0.04, 0.08], [law_error(0.04), law_error(0.08)])}
    assert envelope_error(curves, 0.03) is None
    assert [(p.series, p.from_s, p.to_s) for p in envelope_pieces(curves)] == [
        ("early", pytest.approx(0.01), pytest.approx(0.02)),
        ("late", pytest.approx(0.04), pytest.approx(0.08))]


def test_the_envelope_time_at_an_error_is_the_earliest_curve_to_reach_it():
    curves = two_curves()                               # both measured at 0.01..0.16 s
    early = law_error(0.03)                             # flat reaches it first
    found = envelope_seconds(curves, early)
    assert (found.placement, found.series) == ("in", "flat")
    assert found.seconds == pytest.approx(0.03) and steep_seconds(early) > 0.03
    late = steep_error(0.12)                            # steep reaches it at 0.12 s
    found = envelope_seconds(curves, late)
    assert (found.placement, found.series) == ("in", "steep")
    assert found.seconds == pytest.approx(0.12)
    # The speed-up is the earliest curve's: 4x at 0.03 s over a point at 0.0075 s.
    assert speedup(curves, late, 0.03).value == pytest.approx(4.0)
    assert speedup(curves, late, 0.03).via == "steep"


def test_the_envelope_time_is_a_bound_where_the_curves_do_not_tell():
    # flat's smallest error is reached at 0.16 s; steep reaches it at ~0.087 s.
    curves = two_curves()
    beyond = steep_error(0.14)     # below flat's range, steep reaches it at 0.14 < 0.16: exact
    assert envelope_seconds(curves, beyond).placement == "in"
    # Steep measured only up to 0.08 s: an error it reaches at 0.1 s is beyond it, and flat
    # reaches it after its own range (0.16 s) ends: every curve ends above it.
    short = {"flat": curves["flat"], "steep": baseline_curve(
        [0.01 * n for n in (1, 2, 4, 8)], [steep_error(0.01 * n) for n in (1, 2, 4, 8)])}
    found = envelope_seconds(short, steep_error(0.1))
    assert (found.placement, found.seconds) == ("below", pytest.approx(0.08))
    assert speedup(short, steep_error(0.1), 0.02).text() == "> 4"
    # Steep measured only from 0.02 s: an error flat reaches at 0.012 s but whose steep time
    # would be before 0.02 s is no problem (steep is worse there) ...
    late_start = two_curves(steep_from=0.02)
    assert envelope_seconds(late_start, law_error(0.012)).placement == "in"
    # ... but a curve whose cheapest point (0.02 s) already beats the error flat reaches at
    # 0.015 s might reach it sooner: flat's time is only an upper bound.
    halved = {"flat": curves["flat"], "better": baseline_curve(
        [0.02 * n for n in SPP], [law_error(0.02 * n) / 2 for n in SPP])}
    found = envelope_seconds(halved, law_error(0.015))
    assert (found.placement, found.series) == ("above", "flat")
    assert found.seconds == pytest.approx(0.015) and "cheapest" in found.note
    # Flat reaches an error at 0.14 s in its range; steep's range ends at 0.08 s above it:
    # steep might reach it sooner, so the flat time is only an upper bound.
    found = envelope_seconds(short, law_error(0.14))
    assert (found.placement, found.series, found.seconds) == ("above", "flat",
                                                              pytest.approx(0.14))
    assert "steep" in found.note


def test_the_bootstrap_interval_covers_the_envelope_speed_up():
    """The method 3x faster than the steep curve at an error steep reaches first: over 20
    data sets the interval covers 3 in >= 80 %; against the flat curve alone (a planted
    envelope that drops the series better at large times) it rarely does."""
    rng = np.random.default_rng(11)
    target = 0.08                               # flat reaches this error at ~0.12 s
    assert 0.1 < law_seconds(steep_error(target)) < 0.16
    truth, hits, planted_hits = 3.0, 0, 0
    for _ in range(20):
        flat = [_noisy(rng, 0.01 * n) for n in SPP]
        steep = [Sample(errors=steep_error(0.01 * n) * rng.lognormal(0.0, 0.15, 8),
                        seconds=0.01 * n * rng.lognormal(0.0, 0.03, 3)) for n in SPP]
        point = Sample(errors=steep_error(target) * rng.lognormal(0.0, 0.15, 8),
                       seconds=target / truth * rng.lognormal(0.0, 0.03, 3))
        result = bootstrap_speedup({"flat": flat, "steep": steep}, point, resamples=200,
                                   seed=int(rng.integers(1e9)))
        hits += covers(result, truth)
        planted_hits += covers(bootstrap_speedup({"flat": flat}, point, resamples=200), truth)
    assert hits >= 16, hits
    assert planted_hits <= 3, planted_hits
