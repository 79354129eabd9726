"""The lower envelope of several error-against-time curves: the strongest PT's curve
(docs/pareto.md, "The strongest PT"), one for all, so that the Pareto study's speed-ups
(jobs/pareto/tradeoff.py) and the charts that draw it (jobs/views/charts.py, plots.py)
use one envelope.

A curve is a series' own front, sorted by time, so error falls strictly as time grows,
piecewise linear in log-log (log seconds against log error) over its measured time range
only; at a time t the envelope is the least error of the curves whose range contains t,
and a time no range contains is a gap.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import combinations, pairwise

import numpy as np

from jobs.views.front import pareto_front


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


def curve_error(curve: Curve, seconds: float) -> float:
    """The curve's error at ``seconds`` within its time range (log-log interpolation)."""
    return float(np.exp(np.interp(np.log(seconds), np.log(curve.seconds), np.log(curve.errors))))


def envelope_error(curves: Mapping[str, Curve], seconds: float) -> tuple[float, str] | None:
    """The lower envelope at ``seconds``: the least error of the curves whose measured time
    range contains it, and that curve's name; None in a gap (no range contains it)."""
    found = [(curve_error(curve, seconds), name) for name, curve in curves.items()
             if curve.seconds[0] <= seconds <= curve.seconds[-1]]
    return min(found) if found else None


@dataclass(frozen=True)
class Piece:
    """A time interval [from_s, to_s] over which ``series``' curve is the envelope."""

    series: str
    from_s: float
    to_s: float


def envelope_pieces(curves: Mapping[str, Curve]) -> list[Piece]:
    """The envelope as the time intervals each curve is lowest over (neighbours of one curve
    merged; a gap lies in no interval). Between two consecutive times of any curve every
    curve is one straight line in log-log, so two curves cross there at most once: the
    crossings and those times cut the axis into intervals with one lowest curve each."""
    logs = {name: (np.log(c.seconds), np.log(c.errors)) for name, c in curves.items()}
    times = sorted({float(t) for log_t, _ in logs.values() for t in log_t})
    cuts = set(times)
    for a, b in pairwise(times):
        lines = [(np.interp([a, b], log_t, log_e)) for log_t, log_e in logs.values()
                 if log_t[0] <= a and b <= log_t[-1]]
        for (ea, eb), (fa, fb) in combinations(lines, 2):
            if (ea - fa) * (eb - fb) < 0:
                cuts.add(a + (b - a) * (ea - fa) / ((ea - fa) - (eb - fb)))
    pieces: list[Piece] = []
    for a, b in pairwise(sorted(cuts)):
        found = envelope_error(curves, float(np.exp((a + b) / 2)))
        if found is None:
            continue
        start, end = float(np.exp(a)), float(np.exp(b))
        if pieces and pieces[-1].series == found[1] and pieces[-1].to_s == start:
            pieces[-1] = Piece(found[1], pieces[-1].from_s, end)
        else:
            pieces.append(Piece(found[1], start, end))
    return pieces


def envelope_line(curves: Mapping[str, Curve]) -> list[list[tuple[float, float]]]:
    """The envelope as polylines (seconds, error), one per stretch without a gap: each
    piece's ends and its curve's points between them, which a log-log plot joins
    exactly (the curves are straight lines in log-log between their points)."""
    lines: list[list[tuple[float, float]]] = []
    for piece in envelope_pieces(curves):
        curve = curves[piece.series]
        inside = [float(t) for t in curve.seconds if piece.from_s < t < piece.to_s]
        stretch = [(t, curve_error(curve, t)) for t in (piece.from_s, *inside, piece.to_s)]
        if lines and lines[-1][-1][0] == piece.from_s:
            lines[-1] += stretch[1:]
        else:
            lines.append(stretch)
    return lines
