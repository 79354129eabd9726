"""`adaptive`: the per-pixel termination of the NIRC paper (Sec. 6.3).

At the first vertex v1 a path terminates where its pixel's v1 mask allows
(``CacheState.v1_allowed``; the mask comes from the relative bias of the
converged cache-at-v1 image and is set on the integrator with
``set_v1_mask``; without one every pixel may), at later vertices by the spread
heuristic (sph.py). N_c may differ at v1 and later (``nc=[8, 1]``: 8 cache
samples at v1, 1 afterwards — the paper's "NIRC equal time" series varies the
first), so it takes two N_c values and defaults to one sample.
"""

from __future__ import annotations

from typing import Any

from renderers.integrators.termination import TerminationPolicy, TerminationQuery, register
from renderers.integrators.termination.sph import spread_stop, weight_of


@register
class AdaptiveTermination(TerminationPolicy):
    name = "adaptive"
    description = "per-pixel v1 mask at the first vertex, then SPH (NIRC paper Sec. 6.3)"
    serves = frozenset({"incident", "outgoing"})
    nc_entries = 2
    default_nc = (1,)

    def continuation(self, query: TerminationQuery) -> tuple[Any, Any]:
        import drjit as dr

        spread = spread_stop(query, self.settings)
        stop = dr.select(query.vertex.depth == 0, query.state.v1_allowed, spread)
        return weight_of(stop), query.state
