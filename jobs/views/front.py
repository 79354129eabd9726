"""The Pareto front of (time, error) points: one for all, so that every study and the
charts draw the same front (a point is on it when no other point is at least as fast
and at least as accurate, and strictly better in one)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def pareto_front(seconds: Sequence[float | None], errors: Sequence[float | None]) -> list[bool]:
    """Which points are on the front: no other point has time <= and error <= with one
    of them strictly smaller. A point without a finite time or error is not on it."""
    points = [(t, e) if finite(t) and finite(e) else None
              for t, e in zip(seconds, errors, strict=True)]
    return [p is not None and not any(q is not None and q[0] <= p[0] and q[1] <= p[1]
                                      and q != p for q in points)
            for p in points]


def finite(value: float | None) -> bool:
    """A number that is there and finite."""
    return value is not None and bool(np.isfinite(value))
