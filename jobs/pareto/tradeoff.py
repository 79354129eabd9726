"""Error against time: the Pareto front, and the speed-up at equal error over the baseline.

Pure arithmetic on measured points (seconds per frame, error), no rendering;
``jobs/pareto/pareto.py`` measures the points and docs/pareto.md states the
method:

- the **front**: the points no other point beats in both time and error;
- a baseline **curve**: a series' own front, sorted by time, so error falls
  strictly as time grows, interpolated piecewise-linearly in log-log (log
  seconds against log error); a power law error = c · t^-a is exact on it;
- a baseline of several curves (the strongest PT) is their **lower envelope** at
  equal time (:data:`ENVELOPE_DEFINITION`); one curve is its own envelope;
- the **speed-up** of a point at equal error: t_baseline(its error) / its time,
  where the envelope's time at an error is the least of its curves' times at it.
  An error outside a curve's measured errors is never extrapolated: the
  speed-up is then a bound, '> x' (the point's error is below every curve's
  smallest: the baseline would need more than its longest time) or '< x' (the
  baseline may reach it sooner than measured: a curve's cheapest point is
  already better, or a curve whose range ends earlier is not known there);
- its **confidence interval**: a percentile bootstrap resampling, independently,
  every point's seeds (the error is their mean) and timing samples (the time is
  their median), baseline points and the point alike, and recomputing the
  curves and the speed-up. A replicate outside the baseline's range counts as
  -inf or +inf, so an end of the interval the measured range cannot bound is
  None.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal, NamedTuple

import numpy as np

from jobs.views.envelope import Curve, baseline_curve
from jobs.views.front import finite

#: Defaults of the bootstrap: replicates, confidence level, generator seed.
RESAMPLES = 2000
CONFIDENCE = 0.95
BOOTSTRAP_SEED = 0

BOOTSTRAP_METHOD = (
    "percentile bootstrap: each replicate resamples, with replacement and independently, "
    "every point's per-seed errors (error = their mean) and its timing samples (time = their "
    "median), the baseline's points and the method's point alike, and recomputes the "
    "baseline's monotone log-log curves (their envelope) and the speed-up; replicates outside "
    "the baseline's range count as -inf / +inf (an interval end they decide is reported as "
    "unbounded)")

#: What the baseline of several curves is (docs/pareto.md, "The strongest PT").
ENVELOPE_DEFINITION = (
    "lower error envelope at equal time of the baseline's curves: each curve is its series' "
    "own front, piecewise linear in log-log between its points, over its measured time range "
    "only (never extrapolated); at a time t the envelope is the least error of the curves whose "
    "range contains t, and a time no range contains is a gap (no envelope there). Its time at "
    "an error e is the earliest time any curve reaches e: the least of the curves' times at e. "
    "A curve whose errors end above e (its most expensive point is worse) is known to need "
    "more than its longest time, and one whose cheapest point is already below e less than "
    "its shortest time. The time is exact when the least exact time is no larger than every "
    "such lower bound; otherwise the measured curves bound it from above ('<' speed-up), or, "
    "when every curve ends above e, from below ('>' speed-up)")


@dataclass(frozen=True)
class Sample:
    """One measured point: per-seed errors and timing samples (seconds per frame)."""

    errors: Sequence[float]
    seconds: Sequence[float]

    @property
    def error(self) -> float:
        return float(np.mean(self.errors))

    @property
    def time(self) -> float:
        return float(np.median(self.seconds))


#: Where an error lies against the baseline's measured errors.
Placement = Literal["in", "below", "above"]


def equal_error_seconds(curve: Curve, error: float) -> tuple[float, Placement]:
    """The baseline's time at ``error`` (log-log interpolation) and 'in' if the
    error is within its measured errors; else the time at the nearest end, with
    'below' (the error is smaller than the baseline's smallest: its time is a
    lower bound) or 'above' (larger than its largest: an upper bound)."""
    if error < curve.errors[-1]:
        return float(curve.seconds[-1]), "below"
    if error > curve.errors[0]:
        return float(curve.seconds[0]), "above"
    log_t = np.interp(np.log(error), np.log(curve.errors[::-1]), np.log(curve.seconds[::-1]))
    return float(np.exp(log_t)), "in"


class EqualError(NamedTuple):
    """The baseline's time at an error: ``seconds``, exact ('in') or a bound ('below': a
    lower bound, 'above': an upper bound), the curve that gives it, and why a bound."""

    seconds: float
    placement: Placement
    series: str
    note: str


def envelope_seconds(curves: Mapping[str, Curve], error: float) -> EqualError:
    """The envelope's time at ``error`` (:data:`ENVELOPE_DEFINITION`): the least of the
    curves' times at it, each known to lie in [low, high]."""
    spans = []
    for name, curve in curves.items():
        seconds, placement = equal_error_seconds(curve, error)
        low, high = {"in": (seconds, seconds), "below": (seconds, np.inf),
                     "above": (0.0, seconds)}[placement]
        spans.append((low, high, name))
    high, high_name = min((high, name) for _, high, name in spans)
    low, low_name = min((low, name) for low, _, name in spans)
    if not np.isfinite(high):
        return EqualError(low, "below", low_name,
                          "error below the baseline's measured range (its most expensive "
                          "point is worse): speed-up is at least this")
    if low == high:
        return EqualError(high, "in", high_name, "")
    if low == 0.0:
        return EqualError(high, "above", high_name,
                          "error above a baseline curve's measured range (its cheapest point "
                          "is better): speed-up is at most this")
    return EqualError(high, "above", high_name,
                      f"{low_name}'s measured range ends before this time and might reach "
                      "this error sooner: speed-up is at most this")


@dataclass(frozen=True)
class Speedup:
    """Speed-up at equal error over the baseline.

    ``relation`` '=': ``value`` is the speed-up; '>' / '<': the error is outside the
    baseline's range and ``value`` is a lower / upper bound; 'n/a': no value (``note``
    says why). ``ci95``: [lo, hi] of the bootstrap, an end None where replicates
    outside the baseline's range decide it; None without a bootstrap. ``against``:
    the baseline's label; ``via``: its curve whose time gives the value.
    """

    value: float | None
    relation: Literal["=", ">", "<", "n/a"]
    ci95: list[float | None] | None = None
    note: str = ""
    against: str = ""
    via: str = ""

    def text(self) -> str:
        """'2.31', '> 4.1', '< 0.5' or 'n/a'."""
        if self.value is None:
            return "n/a"
        return f"{self.value:.3g}" if self.relation == "=" else f"{self.relation} {self.value:.3g}"


_RELATION: dict[Placement, Literal["=", ">", "<"]] = {"in": "=", "below": ">", "above": "<"}


def speedup(curves: Mapping[str, Curve], error: float, seconds: float) -> Speedup:
    """t_baseline(error) / seconds on the envelope of ``curves``, or its bound."""
    if not (finite(error) and error > 0 and finite(seconds) and seconds > 0):
        return Speedup(None, "n/a", note="no positive finite error and time")
    found = envelope_seconds(curves, error)
    return Speedup(found.seconds / seconds, _RELATION[found.placement], note=found.note,
                   via=found.series)


def sample_curves(baseline: Mapping[str, Sequence[Sample]]) -> dict[str, Curve]:
    """Each baseline series' curve through its samples' times and errors."""
    return {name: baseline_curve([s.time for s in samples], [s.error for s in samples])
            for name, samples in baseline.items()}


def bootstrap_speedup(baseline: Mapping[str, Sequence[Sample]], point: Sample, *,
                      against: str = "", resamples: int = RESAMPLES,
                      confidence: float = CONFIDENCE, seed: int = BOOTSTRAP_SEED) -> Speedup:
    """:func:`speedup` of ``point`` on the envelope of the ``baseline`` series' curves
    (series name -> its points), with the percentile bootstrap interval of the module
    docstring; ``against`` names the baseline."""
    estimate = speedup(sample_curves(baseline), point.error, point.time)
    if estimate.relation == "n/a":
        return estimate
    rng = np.random.default_rng(seed)
    replicate_base = {name: [_replicates(rng, s, resamples) for s in samples]
                      for name, samples in baseline.items()}
    errors, times = _replicates(rng, point, resamples)
    values = np.empty(resamples)
    for index in range(resamples):
        curves = {name: baseline_curve([t[index] for _, t in replicates],
                                       [e[index] for e, _ in replicates])
                  for name, replicates in replicate_base.items()}
        one = speedup(curves, errors[index], times[index])
        values[index] = {"=": one.value, ">": np.inf, "<": -np.inf}[one.relation]
    tail = (1.0 - confidence) / 2
    lo, hi = np.quantile(values, [tail, 1.0 - tail], method="inverted_cdf")
    return Speedup(estimate.value, estimate.relation,
                   [float(lo) if np.isfinite(lo) else None, float(hi) if np.isfinite(hi) else None],
                   estimate.note, against, estimate.via)


def _replicates(rng: np.random.Generator, sample: Sample,
                resamples: int) -> tuple[np.ndarray, np.ndarray]:
    """``resamples`` bootstrap means of the seeds' errors and medians of the timings."""
    errors, seconds = np.asarray(sample.errors, float), np.asarray(sample.seconds, float)
    picks_e = rng.integers(0, errors.size, size=(resamples, errors.size))
    picks_t = rng.integers(0, seconds.size, size=(resamples, seconds.size))
    return errors[picks_e].mean(axis=1), np.median(seconds[picks_t], axis=1)
