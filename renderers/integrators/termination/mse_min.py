"""`mse-min`: MSE-minimizing termination ([VTT24] Sec. 4.3, Eq. 3 and 4;
docs/variance_trading.md, "The MSE rule as read here").

At each vertex a path compares the MSE of an s-sample pixel (s: the sample target)
if it terminated here with the MSE if it terminated one vertex later (Eq. 4 split at
this vertex), greedily:

    current  = S / s + g^2 b^2
    deferred = (S + P) / s + g^2 min(d, clamp / margin b^2)
    terminate when current <= margin x deferred

S: the prefixed local variances of the vertices the path continued from (carried in
``CacheState.termination_value``, as variance bounding carries it); P: this vertex's
prefixed local variance (var_bound.py); g: the throughput's luminance; b^2: the
record's average squared bias E[E[Y|y]^2] - E[Y]^2 (Sec. 4.4); d: the deferred squared
bias E[(f cos / p)^2 b_next^2] of the record, "the average bias when terminating at the
next vertex" (Sec. 4.3), which the propagation pass estimates from its own samples
(renderers/caches/moment_grid.py). So the decision depends on the path's prefix only
(Sec. 3): a look-ahead along the path's own continuation sample would make the
decision to stop depend on the sample that continues, and bias the image.
The margin and the clamp are the paper's heuristic factors, whose values and exact
form it does not give; this project's reading is in the docs and in
:func:`renderers.termination_model.mse_min_terminates`, the discrete model's own rule.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from renderers.integrators.termination import TerminationPolicy, TerminationQuery, register
from renderers.integrators.termination.var_bound import prefixed_local_variance


class MSEMinParams(BaseModel):
    """``samples`` s, and the heuristic factors (docs/variance_trading.md)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    samples: float = Field(100.0, gt=0.0, le=1e12, description="sample target s")
    margin: float = Field(1.1, ge=1.0, le=100.0,
                          description="the current MSE may be this factor above the "
                                      "deferred one and still terminate")
    clamp: float = Field(0.9, gt=0.0, le=1.0,
                         description="deferred squared bias at most clamp / margin x the "
                                     "local one")


@register
class MSEMinimizing(TerminationPolicy):
    name = "mse-min"
    description = "greedy MSE minimization at a sample target ([VTT24] Sec. 4.3)"
    serves = frozenset({"grid"})
    Params = MSEMinParams

    def continuation(self, query: TerminationQuery) -> tuple[Any, Any]:
        import drjit as dr
        import mitsuba as mi

        from renderers.termination_model import mse_min_terminates

        here = query.statistics()
        state, vertex = query.state, query.vertex
        local = prefixed_local_variance(query, here.local_variance)
        p = self.params
        # A record without a squared-bias estimate is not read as unbiased: the path
        # goes on, as where there is no record (renderers/caches/moment_grid.py).
        stop = query.usable & here.bias_known & mse_min_terminates(
            state.termination_value, local, dr.square(mi.luminance(vertex.beta)),
            here.squared_bias, here.deferred_bias, p.samples, p.margin, p.clamp)
        state.termination_value = dr.select(query.usable & ~stop,
                                            state.termination_value + local,
                                            state.termination_value)
        return dr.select(stop, mi.Float(0.0), mi.Float(1.0)), state
