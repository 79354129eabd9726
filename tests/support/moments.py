"""Per-pixel mean and variance of any integrator, for statistical tests.

Mitsuba's ``moment`` integrator wraps another integrator and accumulates, per
pixel, the first and second moments of its samples (in CIE XYZ). With a box
reconstruction filter every sample belongs to exactly one pixel, so

    mean = E[X],  var(mean) = (E[X^2] - E[X]^2) / spp

are estimates from *all* samples — far more accurate than a
variance over a handful of passes, which is what a per-pixel z-test with a
multiple-comparison correction needs (Mitsuba's own render tests work this way).

The film accumulates in float32, so a pixel whose samples are (nearly) all
equal, e.g. one that sees only the sky, gets a variance estimate of ~0 while
its mean still carries a rounding error of order 1e-5 relative: a z-test would
flag it with p ~ 1e-50. ``FLOAT32_REL_PRECISION`` adds that rounding error
(as a standard deviation proportional to the mean) to the variance; at 1e-4
relative it is far below any bias a test is meant to detect.
"""

from __future__ import annotations

from typing import Any

import numpy as np

FLOAT32_REL_PRECISION = 1e-4


def _xyz_channels(names: list[str], prefix: str) -> list[int]:
    return [names.index(f"{prefix}.{c}") for c in "XYZ"]


def render_moments(scene: Any, integrator: dict[str, Any], spp: int,
                   seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Return (mean, variance of the mean), each (H, W, 3) in XYZ, of ``integrator``."""
    import mitsuba as mi

    moment = mi.load_dict({"type": "moment", "nested": integrator})
    names = moment.aov_names()
    image = np.asarray(mi.render(scene, integrator=moment, spp=spp, seed=seed), dtype=np.float64)
    # Film channels: the developed RGB first, then the AOVs in aov_names() order.
    first = image[..., [3 + i for i in _xyz_channels(names, "nested")]]
    second = image[..., [3 + i for i in _xyz_channels(names, "m2_nested")]]
    variance = np.maximum(second - first**2, 0.0) / spp + (FLOAT32_REL_PRECISION * first) ** 2
    return first, variance
