"""The spread-angle termination heuristic of the Neural Radiance Cache (SPH).

NRC [MRNK21] terminates a path into the cache once the footprint the path has
spread over is large compared with the footprint of the primary vertex seen
from the camera. We implement the *original NRC form* (docs/estimators.md,
"Spread through delta bounces"), which accumulates a sum of square roots:

    a(x_1 ... x_n) = ( sum_{i=2..n} sqrt( |x_{i-1} - x_i|^2 / (p(w_{i-1}) |cos theta_i|) ) )^2
    a_0            = |x_0 - x_1|^2 / (4 pi |cos theta_1|)
    terminate when a > c * a_0,  c = 0.01.

x_0 is the camera, p(w_{i-1}) the solid-angle pdf of the BSDF sample that led
from x_{i-1} to x_i, theta_i the angle between that ray and the normal at x_i.
The NIRC paper's Eq. 19 as extracted shows a product instead of the sum, and
implementations disagree on a_0 by (4 pi)^2 (NVIDIA's SDK uses 4 pi d^2 / cos);
we follow the paper's Eq. 20 for a_0. A segment that follows a delta BSDF
sample adds no term (a mirror does not widen the footprint; Mitsuba reports
pdf 1 for it): ``update_spread`` in cached.py leaves it out. The functions work
on Python floats and on Dr.Jit arrays alike, so the test can check them on a
hand-computed path.
"""

from __future__ import annotations

import math
from typing import TypeVar

import drjit as dr

T = TypeVar("T")

SPREAD_C = 0.01


def primary_footprint(distance_sq: T, cos_theta: T) -> T:
    """a_0 = |x_0 - x_1|^2 / (4 pi |cos theta_1|) (NIRC paper Eq. 20)."""
    return distance_sq / (4.0 * math.pi * dr.abs(cos_theta))


def spread_increment(distance_sq: T, pdf_prev: T, cos_theta: T) -> T:
    """sqrt(|x_{i-1} - x_i|^2 / (p(w_{i-1}) |cos theta_i|)): one term of the sum in a."""
    return dr.sqrt(distance_sq / (pdf_prev * dr.abs(cos_theta)))


def spread_exceeded(spread_sum: T, a0: T, c: float = SPREAD_C) -> T:
    """The termination test a > c a_0 with a = spread_sum^2 (Eq. 21)."""
    return dr.square(spread_sum) > c * a0
