"""Error against time: the Pareto front, and the speed-up at equal error over the baseline.

Pure arithmetic on measured points (seconds per frame, error), no rendering;
``jobs/pareto/pareto.py`` measures the points and docs/pareto.md states the
method:

- the **front**: the points no other point beats in both time and error;
- the baseline's **curve**: the baseline's own front, sorted by time, so error
  falls strictly as time grows, interpolated piecewise-linearly in log-log
  (log seconds against log error); a power law error = c · t^-a is exact on it;
- the **speed-up** of a point at equal error: t_baseline(its error) / its time.
  An error outside the baseline's measured errors is never extrapolated: the
  speed-up is then a bound, '> x' (the point's error is below the baseline's
  smallest: the baseline would need more than its longest time) or '< x' (above
  its largest);
- its **confidence interval**: a percentile bootstrap resampling, independently,
  every point's seeds (the error is their mean) and timing samples (the time is
  their median), baseline points and the point alike, and recomputing the
  curve and the speed-up. A replicate outside the baseline's range counts as
  -inf or +inf, so an end of the interval the measured range cannot bound is
  None.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from jobs.protocol.front import finite, pareto_front

#: Defaults of the bootstrap: replicates, confidence level, generator seed.
RESAMPLES = 2000
CONFIDENCE = 0.95
BOOTSTRAP_SEED = 0

BOOTSTRAP_METHOD = (
    "percentile bootstrap: each replicate resamples, with replacement and independently, "
    "every point's per-seed errors (error = their mean) and its timing samples (time = their "
    "median), the baseline's points and the method's point alike, and recomputes the "
    "baseline's monotone log-log curve and the speed-up; replicates outside the baseline's "
    "range count as -inf / +inf (an interval end they decide is reported as unbounded)")


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


@dataclass(frozen=True)
class Curve:
    """The baseline's monotone curve: times strictly increasing, errors strictly falling."""

    seconds: np.ndarray
    errors: np.ndarray


def baseline_curve(seconds: Sequence[float], errors: Sequence[float]) -> Curve:
    """The baseline's own front (dominated points dropped: a slower point with more
    error is noise or overhead), sorted by time; ValueError if a time or error is not
    positive (the curve is in log-log)."""
    t, e = np.asarray(seconds, float), np.asarray(errors, float)
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(e)) and np.all(t > 0)
            and np.all(e > 0)):
        raise ValueError("the baseline's times and errors must be positive and finite")
    keep = np.asarray(pareto_front(list(t), list(e)))
    points = sorted(set(zip(t[keep], e[keep], strict=True)))
    return Curve(np.array([p[0] for p in points]), np.array([p[1] for p in points]))


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


@dataclass(frozen=True)
class Speedup:
    """Speed-up at equal error over the baseline.

    ``relation`` '=': ``value`` is the speed-up; '>' / '<': the error is outside the
    baseline's range and ``value`` is a lower / upper bound; 'n/a': no value (``note``
    says why). ``ci95``: [lo, hi] of the bootstrap, an end None where replicates
    outside the baseline's range decide it; None without a bootstrap.
    """

    value: float | None
    relation: Literal["=", ">", "<", "n/a"]
    ci95: list[float | None] | None = None
    note: str = ""

    def text(self) -> str:
        """'2.31', '> 4.1', '< 0.5' or 'n/a'."""
        if self.value is None:
            return "n/a"
        return f"{self.value:.3g}" if self.relation == "=" else f"{self.relation} {self.value:.3g}"


_RELATION: dict[Placement, Literal["=", ">", "<"]] = {"in": "=", "below": ">", "above": "<"}


def speedup(curve: Curve, error: float, seconds: float) -> Speedup:
    """t_baseline(error) / seconds, or its bound outside the baseline's range."""
    if not (finite(error) and error > 0 and finite(seconds) and seconds > 0):
        return Speedup(None, "n/a", note="no positive finite error and time")
    baseline_s, placement = equal_error_seconds(curve, error)
    note = {"in": "",
            "below": "error below the baseline's measured range (its most expensive point "
                     "is worse): speed-up is at least this",
            "above": "error above the baseline's measured range (its cheapest point is "
                     "better): speed-up is at most this"}[placement]
    return Speedup(baseline_s / seconds, _RELATION[placement], note=note)


def bootstrap_speedup(baseline: Sequence[Sample], point: Sample, *,
                      resamples: int = RESAMPLES, confidence: float = CONFIDENCE,
                      seed: int = BOOTSTRAP_SEED) -> Speedup:
    """:func:`speedup` of ``point`` on the curve of the ``baseline`` points, with the
    percentile bootstrap interval of the module docstring."""
    estimate = speedup(baseline_curve([s.time for s in baseline], [s.error for s in baseline]),
                       point.error, point.time)
    if estimate.relation == "n/a":
        return estimate
    rng = np.random.default_rng(seed)
    replicate_base = [_replicates(rng, s, resamples) for s in baseline]
    errors, times = _replicates(rng, point, resamples)
    values = np.empty(resamples)
    for index in range(resamples):
        curve = baseline_curve([t[index] for _, t in replicate_base],
                               [e[index] for e, _ in replicate_base])
        one = speedup(curve, errors[index], times[index])
        values[index] = {"=": one.value, ">": np.inf, "<": -np.inf}[one.relation]
    tail = (1.0 - confidence) / 2
    lo, hi = np.quantile(values, [tail, 1.0 - tail], method="inverted_cdf")
    return Speedup(estimate.value, estimate.relation,
                   [float(lo) if np.isfinite(lo) else None, float(hi) if np.isfinite(hi) else None],
                   estimate.note)


def _replicates(rng: np.random.Generator, sample: Sample,
                resamples: int) -> tuple[np.ndarray, np.ndarray]:
    """``resamples`` bootstrap means of the seeds' errors and medians of the timings."""
    errors, seconds = np.asarray(sample.errors, float), np.asarray(sample.seconds, float)
    picks_e = rng.integers(0, errors.size, size=(resamples, errors.size))
    picks_t = rng.integers(0, seconds.size, size=(resamples, seconds.size))
    return errors[picks_e].mean(axis=1), np.median(seconds[picks_t], axis=1)
