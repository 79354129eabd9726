"""`bth`: NIRC's Balanced Termination Heuristic.

Continue with probability P_s = p(w) / (p(w) + N_c / pi) (NIRC paper Eq. 22-23),
p the full BSDF pdf of the continuation direction w, N_c the number of cache
samples at the first vertex; after the first vertex also stop where the spread
heuristic says so (sph.py). Where the continuation sample picked a delta lobe,
the decision for the smooth part is drawn with a virtual smooth sample instead
(its full pdf), so the smooth part is cached with the same probability as in
the smooth branch. For NIRC's cache of incident radiance only: the heuristic
balances the cache's N_c samples against the one continuation sample.
"""

from __future__ import annotations

import math
from typing import Any

from renderers.integrators.termination import TerminationPolicy, TerminationQuery, register
from renderers.integrators.termination.sph import spread_stop, weight_of


def continue_pdf(query: TerminationQuery) -> Any:
    """Full BSDF pdf p(w) for Eq. 22: of the continuation w where it is a smooth
    sample, else of a virtual smooth sample (the decision is about the smooth part)."""
    import drjit as dr
    import mitsuba as mi

    from renderers.integrators.cached import smooth_context

    vertex, usable = query.vertex, query.usable
    si, bsdf, bs = vertex.si, vertex.bsdf, vertex.bsdf_sample
    delta = usable & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
    virtual, _ = bsdf.sample(smooth_context(), si, vertex.sampler.next_1d(delta),
                             vertex.sampler.next_2d(delta), delta)
    pdf_virtual = bsdf.pdf(mi.BSDFContext(), si, virtual.wo, delta)
    return dr.select(delta, pdf_virtual, bs.pdf)


@register
class BalancedTermination(TerminationPolicy):
    name = "bth"
    description = "Balanced Termination Heuristic (NIRC paper Eq. 22-23), then SPH"
    serves = frozenset({"incident"})

    def continuation(self, query: TerminationQuery) -> tuple[Any, Any]:
        spread = spread_stop(query, self.settings)
        pdf = continue_pdf(query)
        p_continue = pdf / (pdf + self.settings.nc[0] / math.pi)
        xi = query.vertex.sampler.next_1d(query.usable)
        return weight_of((xi > p_continue) | spread), query.state
