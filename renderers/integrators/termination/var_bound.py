"""`var-bound`: variance-bounding termination ([VTT24] Sec. 4.2, Eq. 1, 2 and 5;
docs/variance_trading.md).

The variance of a path-traced pixel is the expected sum of the prefixed local variances
P_j = (g_j^pre)^2 V E[g_j^surf | x_{j+1}] of its vertices (Eq. 1); a path cut at
l(X) keeps the first l(X) terms (Eq. 2). So a path that keeps its own sum S under a
threshold t bounds the pixel's variance by t: continue while S + P_j <= t, and at the
vertex whose P_l would cross t blend the cache with one more segment, weight
alpha = sqrt((t - S) / P_l) (Eq. 5), so that S + alpha^2 P_l = t.

Here g^pre is the luminance of the path throughput at the vertex and the local variance
the record's *average* variance E[Y^2] - E[E[Y|y]^2] (Sec. 4.4; the plain variance
E[Y^2] - E[Y]^2 would also count the spread of E[Y|y] across the cell, which is bias).
S is carried in ``CacheState.termination_value``. The weight and the comparison are
:func:`renderers.termination_model.variance_bound_weight`, the discrete model's own.

``relative``: t is relative to the pixel's brightness; the absolute threshold is t
times the squared luminance of the pixel estimated from the cache at the first hit
(its emission plus the cache's reflected radiance, Sec. 5), kept along the path as
this policy's own ``scale`` (:meth:`VarianceBounding.path_state`). Where the first hit
has no record, the first vertex that has one estimates the pixel (the light gathered
so far plus the throughput times its record), and the path is not bounded before it:
a brightness of 0 would make the threshold 0 and end every such path at its next
vertex. Not counted: the variance of the first hit within the pixel (P_0 of Eq. 1,
the pixel footprint), which no record estimates.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from renderers.integrators.termination import TerminationPolicy, TerminationQuery, register


class VarBoundParams(BaseModel):
    """``threshold`` t (absolute luminance variance, or relative with ``relative``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    threshold: float = Field(0.1, ge=0.0, le=1e12, description="variance threshold t")
    relative: bool = Field(False, description="t relative to the squared pixel brightness "
                                              "estimated from the cache at the first hit")


def prefixed_local_variance(query: TerminationQuery, local_variance: Any) -> Any:
    """P_j = (g_j^pre)^2 V E[g^surf | x_{j+1}] with g^pre the throughput's luminance."""
    import drjit as dr
    import mitsuba as mi

    return dr.square(mi.luminance(query.vertex.beta)) * local_variance


@register
class VarianceBounding(TerminationPolicy):
    name = "var-bound"
    description = "variance bounding with alpha blend ([VTT24] Sec. 4.2, Eq. 5)"
    serves = frozenset({"grid"})
    Params = VarBoundParams
    blends = True

    def path_state(self) -> dict[str, Any]:
        """``relative``: the squared pixel brightness, set at the first vertex with a
        record (Sec. 5), and whether it is set."""
        import mitsuba as mi

        return ({"scale": mi.Float(1.0), "scaled": mi.Bool(False)} if self.params.relative
                else {})

    def continuation(self, query: TerminationQuery) -> tuple[Any, Any]:
        import drjit as dr
        import mitsuba as mi

        from renderers.termination_model import variance_bound_weight

        stats = query.statistics()
        state, vertex = query.state, query.vertex
        bounded = query.usable
        if self.params.relative:
            # Sec. 5: the pixel's brightness from the cache at the first hit, or at the
            # first vertex with a record where the first hit has none (module doc).
            own = state.policy_state
            first = vertex.active & stats.found & ~own["scaled"]
            brightness = mi.luminance(vertex.L + vertex.beta * stats.radiance)
            own["scale"] = dr.select(first, dr.square(brightness), own["scale"])
            own["scaled"] |= first
            bounded &= own["scaled"]
            threshold = self.params.threshold * own["scale"]
        else:
            threshold = mi.Float(self.params.threshold)
        local = prefixed_local_variance(query, stats.local_variance)
        alpha = variance_bound_weight(state.termination_value, local, threshold)
        alpha = dr.select(bounded, alpha, 1.0)
        # What the path keeps of Eq. 2: the full P where it continues, alpha^2 P where
        # it blends (Eq. 5); nothing where it stops.
        state.termination_value = dr.select(bounded,
                                            state.termination_value + dr.square(alpha) * local,
                                            state.termination_value)
        return alpha, state
