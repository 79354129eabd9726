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

Also here: mse-min's decisions depend on the path's prefix only (the same paths with
another continuation sample stop at the same vertices; a look-ahead along the path's
own continuation, planted, does not), and relative var-bound takes the pixel's
brightness from the first vertex with a record where the first hit has none.
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


# ---- mse-min decides on the path's prefix ------------------------------------------

class _AskedTwice:
    """Asks ``policy`` at every vertex twice: with the vertex's own continuation sample
    and with another one (the direction mirrored about the normal's axis, the weight
    scaled by 0.3), the path state as it came each time; counts in ``differ`` the lanes whose
    two decisions differ, and answers the first."""

    def __init__(self, policy) -> None:
        import drjit as dr
        import mitsuba as mi

        self.policy = policy
        self.differ = dr.zeros(mi.UInt32, 1)

    def path_state(self) -> dict:
        return self.policy.path_state()

    def continuation(self, query):
        import dataclasses

        import drjit as dr
        import mitsuba as mi

        vertex, before = query.vertex, query.state.termination_value
        alpha, state = self.policy.continuation(query)
        after, state.termination_value = state.termination_value, before
        sample = mi.BSDFSample3f(vertex.bsdf_sample)
        sample.wo = mi.Vector3f(-sample.wo.x, -sample.wo.y, sample.wo.z)
        other = dataclasses.replace(vertex, bsdf_sample=sample,
                                    bsdf_weight=0.3 * vertex.bsdf_weight)
        other_alpha, state = self.policy.continuation(
            dataclasses.replace(query, vertex=other, state=state))
        state.termination_value = after
        dr.scatter_add(self.differ, mi.UInt32(1), mi.UInt32(0),
                       query.usable & (alpha != other_alpha))
        return alpha, state


def _differing_decisions(mi, filled) -> int:  # noqa: F811
    asked = _AskedTwice(_policy("mse-min", {"samples": 100.0}))
    _frames(mi, filled, asked, 4)
    print("differing decisions", int(asked.differ[0]))
    return int(asked.differ[0])


def test_mse_min_decides_on_the_prefix_only(mi, filled, monkeypatch):  # noqa: F811
    """[VTT24] Sec. 3 and 4.3: the decision to stop at a vertex depends on the path's
    prefix, and the deferred squared bias is the record's average over next vertices,
    so the same path with another continuation sample is stopped at the same vertices.
    Planted: the deferred bias read at the vertex the path's own continuation reaches
    (a look-ahead ray, lum(f cos / p)^2 b^2 there), whose decision moves with the
    sample that continues the path and biases the image."""
    assert _differing_decisions(mi, filled) == 0

    import dataclasses

    import drjit as dr

    from renderers.integrators.termination import TerminationQuery

    grid = filled[4]
    real = TerminationQuery.statistics

    def looking_ahead(self):
        vertex = self.vertex
        ray = vertex.si.spawn_ray(vertex.si.to_world(vertex.bsdf_sample.wo))
        hit = vertex.scene.ray_intersect(ray, self.usable)
        ahead = grid.lookup(hit.p, hit.sh_frame.n, None, self.usable & hit.is_valid())
        return dataclasses.replace(real(self), deferred_bias=dr.square(
            mi.luminance(vertex.bsdf_weight)) * ahead.squared_bias)

    monkeypatch.setattr(TerminationQuery, "statistics", looking_ahead)
    assert _differing_decisions(mi, filled) > 0


# ---- relative var-bound where the first hit has no record -----------------------------

def _hiding_first_records(monkeypatch) -> None:
    """The render's lookups find no record at the first hit (as in a scene whose visible
    cells are not explored yet)."""
    import dataclasses

    import drjit as dr

    from renderers.integrators.grid_cache import GridCacheIntegrator

    real = GridCacheIntegrator.vertex_terms

    def hiding(self, vertex, state):
        grid, lookup = self.grid, type(self.grid).lookup
        kept = vertex.depth > 0

        def later_only(*args):
            value = lookup(grid, *args)
            return dataclasses.replace(value, radiance=dr.select(kept, value.radiance, 0.0),
                                       found=value.found & kept,
                                       bias_known=value.bias_known & kept)

        grid.lookup = later_only
        try:
            return real(self, vertex, state)
        finally:
            del grid.lookup

    monkeypatch.setattr(GridCacheIntegrator, "vertex_terms", hiding)


def _relative_length(mi, filled, policy=None) -> float:  # noqa: F811
    policy = policy or _policy("var-bound", {"threshold": 1.0, "relative": True})
    return _frames(mi, filled, policy, FRAMES)[1]


def test_relative_var_bound_scales_by_the_first_record_found(mi, filled,  # noqa: F811
                                                             monkeypatch):
    """Where the first hit has no record, the first vertex with one estimates the pixel's
    brightness and the bound starts there: paths are no shorter than where the first
    hit has its record (measured 16x16, t = 1: 4.86 vertices against 3.98). Planted:
    the brightness of a first hit without a record taken as its emission, 0 (the
    threshold 0): paths end at their second vertex (1.83, the light's pixels
    included)."""
    recorded = _relative_length(mi, filled)
    _hiding_first_records(monkeypatch)
    hidden = _relative_length(mi, filled)
    print("relative var-bound lengths", recorded, hidden)
    assert hidden >= 0.95 * recorded

    dark = _policy("var-bound", {"threshold": 1.0, "relative": True})
    monkeypatch.setattr(dark, "path_state", lambda: {"scale": mi.Float(0.0),
                                                     "scaled": mi.Bool(True)})
    planted = _relative_length(mi, filled, dark)
    print("planted", planted)
    assert planted < 0.95 * recorded


# ---- mse-min and records without a squared-bias estimate ---------------------------

class _CountingEnds:
    """Answers ``policy``'s decision and counts, over the lanes asked at a usable record,
    the records without a squared-bias estimate (``unknown``) and the paths ended in one
    (``ended``). ``as_unbiased`` (planted: the old reading) shows the policy every
    record's bias as known, 0 where none was estimated."""

    def __init__(self, policy, as_unbiased: bool = False) -> None:
        import drjit as dr
        import mitsuba as mi

        self.policy, self.as_unbiased = policy, as_unbiased
        self.unknown = dr.zeros(mi.UInt32, 1)
        self.ended = dr.zeros(mi.UInt32, 1)

    def path_state(self) -> dict:
        return self.policy.path_state()

    def continuation(self, query):
        import dataclasses

        import drjit as dr
        import mitsuba as mi

        from renderers.integrators.grid_cache import GridStatistics

        value = query.statistics()
        unknown = query.usable & ~value.bias_known
        if self.as_unbiased:
            query = dataclasses.replace(query, cache=GridStatistics(
                dataclasses.replace(value, bias_known=value.found)))
        alpha, state = self.policy.continuation(query)
        dr.scatter_add(self.unknown, mi.UInt32(1), mi.UInt32(0), unknown)
        dr.scatter_add(self.ended, mi.UInt32(1), mi.UInt32(0), unknown & (alpha < 1.0))
        return alpha, state


def _ends_in_unknown_bias(mi, filled, as_unbiased: bool = False) -> tuple[int, int]:  # noqa: F811
    counting = _CountingEnds(_policy("mse-min", {"samples": 100.0}), as_unbiased)
    _frames(mi, filled, counting, 1)
    print("queries at records without a bias estimate, paths ended there",
          int(counting.unknown[0]), int(counting.ended[0]))
    return int(counting.unknown[0]), int(counting.ended[0])


def test_mse_min_does_not_end_paths_where_the_bias_is_unknown(mi, filled):  # noqa: F811
    """A record updated from one vertex at a time has no squared-bias estimate (a pass
    forms it from two of its vertices); the MSE rule must not read its stored 0 as
    unbiased. Paths reach such records (the check has something to reject) and none
    ends in one. Planted: the old reading (every record's bias known, 0 where none was
    estimated) ends paths there."""
    unknown, ended = _ends_in_unknown_bias(mi, filled)
    assert unknown > 0 and ended == 0
    _unknown, ended_planted = _ends_in_unknown_bias(mi, filled, as_unbiased=True)
    assert ended_planted > 0
