"""`grid-cache`'s `mse-min` and `area-spread` policies in a render (renderers/integrators/
termination/mse_min.py, area_spread.py; docs/variance_trading.md).

Their decision rules are checked against the discrete model's on Dr.Jit arrays
(test_grid_cache.py); here they run inside the integrator on the Cornell box with the
pre-filled grid of test_grid_cache.py and move path length the way their parameters
say:

- `mse-min` ([VTT24] Sec. 4.3, Eq. 3-4): a larger sample target s shrinks the variance
  term S / s against the bias term g^2 b^2, so a path stops less often and paths get
  longer;
- `area-spread` (NRC's spread heuristic, a > c a_0): a larger c lets the spread grow
  further before the path stops, so paths get longer.

Measured (16x16, 2 frames): mse-min at s = 1, 1e2, 1e4: 1.10, 1.61, 1.90 vertices;
area-spread at c = 0.01, 100, 1e6: 1.85, 4.09, 5.20.

Planted: a policy whose parameter never reaches its decision (mse-min reading s = 1
whatever it is given) renders the same length, 1.10, at every target and is caught.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.renderers.test_grid_cache import _frames, filled  # noqa: F401 (fixture)

FRAMES = 2


def _policy(name: str, params: dict):
    from renderers.integrators.termination import make_policy, policy_params
    from renderers.methods.grid_cache import GridCacheParams

    return make_policy(policy_params(name, **params), GridCacheParams().termination_settings())


def _length(mi, filled, name: str, params: dict) -> float:  # noqa: F811
    images, length = _frames(mi, filled, _policy(name, params), FRAMES)
    assert np.isfinite(images).all()
    return length


def test_mse_min_paths_get_longer_as_the_sample_target_grows(mi, filled):  # noqa: F811
    lengths = [_length(mi, filled, "mse-min", {"samples": s}) for s in (1.0, 1e2, 1e4)]
    print("mse-min lengths", lengths)
    assert lengths[0] < lengths[1] < lengths[2], lengths


def test_area_spread_paths_get_longer_as_c_grows(mi, filled):  # noqa: F811
    lengths = [_length(mi, filled, "area-spread", {"c": c}) for c in (0.01, 100.0, 1e6)]
    print("area-spread lengths", lengths)
    assert lengths[0] < lengths[1] <= lengths[2], lengths


def test_a_sample_target_that_does_not_reach_the_decision_is_caught(mi, filled,  # noqa: F811
                                                                     monkeypatch):
    from renderers import termination_model

    real = termination_model.mse_min_terminates

    def ignoring_samples(summed, local, g2, bias2, deferred, samples, margin, clamp):
        return real(summed, local, g2, bias2, deferred, 1.0, margin, clamp)

    monkeypatch.setattr(termination_model, "mse_min_terminates", ignoring_samples)
    with pytest.raises(AssertionError):
        test_mse_min_paths_get_longer_as_the_sample_target_grows(mi, filled)
