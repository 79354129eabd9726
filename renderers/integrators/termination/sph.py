"""`sph`: the spread heuristic of the Neural Radiance Cache.

Terminate once the footprint the path has spread over exceeds c times the
primary vertex's footprint, a > c a_0 (NIRC paper Eq. 19-21, in NRC's original
form: renderers/integrators/spread.py), never at the first vertex. c is the
method's ``sph_c``, shared with NRC's self-training paths.
"""

from __future__ import annotations

from typing import Any

from renderers.integrators.termination import (
    TerminationPolicy,
    TerminationQuery,
    TerminationSettings,
    register,
)


def spread_stop(query: TerminationQuery, settings: TerminationSettings) -> Any:
    """Where the spread heuristic ends the path: after the first vertex, a > c a_0 (Eq. 21)."""
    from renderers.integrators.spread import spread_exceeded

    state = query.state
    return (query.vertex.depth > 0) & spread_exceeded(state.spread_sum, state.a0,
                                                      settings.sph_c)


def weight_of(stop: Any) -> Any:
    """The continuation weight of a stop/continue decision: 0 where it stops, else 1."""
    import drjit as dr
    import mitsuba as mi

    return dr.select(stop, mi.Float(0.0), mi.Float(1.0))


@register
class SpreadHeuristic(TerminationPolicy):
    name = "sph"
    description = "spread heuristic (NIRC paper Eq. 19-21)"
    serves = frozenset({"incident", "outgoing"})

    def continuation(self, query: TerminationQuery) -> tuple[Any, Any]:
        return weight_of(spread_stop(query, self.settings)), query.state
