"""The spread-angle heuristic (NRC form) on a hand-computed path."""

from __future__ import annotations

import math

import pytest

from renderers.integrators.spread import primary_footprint, spread_exceeded, spread_increment


def test_spread_heuristic_on_a_hand_computed_path():
    """Camera x0=(0,0,0) -> x1=(0,0,2) -> x2=(1,0,2) -> x3=(1,0,0).

    |x0-x1|^2 = 4, cos theta_1 = 1: a0 = 4 / (4 pi) = 1/pi.
    Diffuse sampling pdfs p = cos/pi; x1->x2 leaves x1 at cos 0.5 (p = 0.5/pi) and
    arrives at x2 with cos theta_2 = 0.8; x2->x3 leaves with p = 0.25/pi and arrives
    with cos theta_3 = 1. Terms: sqrt(1 / (0.5/pi * 0.8)) and sqrt(4 / (0.25/pi)).
    """
    a0 = primary_footprint(4.0, 1.0)
    assert a0 == pytest.approx(1 / math.pi)

    t2 = spread_increment(1.0, 0.5 / math.pi, 0.8)
    t3 = spread_increment(4.0, 0.25 / math.pi, -1.0)  # |cos| is used
    assert t2 == pytest.approx(math.sqrt(2.5 * math.pi))
    assert t3 == pytest.approx(4 * math.sqrt(math.pi))

    a = (t2 + t3) ** 2  # the NRC form: square of the sum of square roots
    assert a == pytest.approx((math.sqrt(2.5 * math.pi) + 4 * math.sqrt(math.pi)) ** 2)
    # With c = 0.01: c a0 = 0.01/pi ~ 0.0032; already the first term exceeds it.
    assert spread_exceeded(t2, a0, 0.01)
    # A path that has barely spread does not terminate.
    assert not spread_exceeded(1e-3, a0, 0.01)
    # The threshold is a > c a0, exactly.
    c = (t2 + t3) ** 2 / a0
    assert not spread_exceeded(t2 + t3, a0, c * 1.0001)
    assert spread_exceeded(t2 + t3, a0, c * 0.9999)
