"""`nrc`: the Neural Radiance Cache [MRNK21] in the shared path-tracing core.

The cache approximates the radiance *reflected* at a vertex toward w_o,
L_r(x, w_o) (direct light included; the vertex's own emission is added by the
path before), albedo-demodulated: the network predicts L_r / (a_d + a_s) and the
query multiplies by a_d + a_s, so it learns the smoother irradiance-like part.

A path terminates into the cache at the first vertex where the spread heuristic
fires (NIRC paper Eq. 19-21 in NRC's original form, spread.py); there it adds
beta * cache(x, w_o) and, since the cache already contains direct light, does
no next-event estimation. Delta lobes continue. One cache query per path, as
in the NIRC paper's NRC baseline (Sec. 6.2).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from renderers.integrators.cached import (
    CachedPathIntegrator,
    CacheState,
    cache_inputs,
    demodulation,
)
from renderers.integrators.path import Vertex, VertexTerms
from renderers.integrators.spread import spread_exceeded

NRC_PLUGIN = "nirc_nrc"


class NRCIntegrator(CachedPathIntegrator):
    """PT core + termination into an outgoing-radiance cache by the spread heuristic."""

    def vertex_terms(self, vertex: Vertex, state: CacheState) -> tuple[VertexTerms, CacheState]:
        smooth = mi.has_flag(vertex.bsdf.flags(), mi.BSDFFlags.Smooth)
        delta = mi.has_flag(vertex.bsdf_sample.sampled_type, mi.BSDFFlags.Delta)
        # ---- Termination by the spread heuristic (Eq. 21); never at the first vertex ----
        stop = (vertex.active_next & smooth & ~delta & (vertex.depth > 0)
                & spread_exceeded(state.spread_sum, state.a0, self.sph_c))
        # ---- Shade the terminal vertex with the cache: L_e (done) + L_r(x, w_o) ----
        inputs = cache_inputs(vertex.si, vertex.bsdf, specular=True)
        surface = self.cache.surface_features(**inputs)
        L_r = self.cache.query(surface, -vertex.ray.d) * demodulation(inputs)
        state.cache_depth = dr.select(stop, vertex.depth + 1, state.cache_depth)
        state.cache_vertices = dr.select(stop, state.cache_vertices + 1, state.cache_vertices)
        terms = VertexTerms(L_add=dr.select(stop, L_r, 0), stop=stop,
                            nee_unweighted=mi.Bool(False), skip_nee=stop)
        return terms, state
