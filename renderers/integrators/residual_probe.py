"""The residual estimator's samples at the primary hit, for V_rel(<F_r>) (docs/metrics.md).

Two-level Monte Carlo at a surface x (NIRC paper Eq. 10-12): the pixel's
estimate is L_e + L_nee + L_c + F_r, with the one-sample residual (N_r = 1,
Eq. 11) along the path's own continuation w

    F_r = (L_ind(x, w) - n(x, w)) f cos / p(w),

L_ind(x, w) estimated by the rest of the path (everything after the emission
the continuation ray hits at y, deeper cache terms included). Eq. 14 is the
variance of this sample. The probe traces paths with the render integrator's
estimator and keeps, per lane whose primary hit is a cache vertex,

    F_r = (L - L_y) + (T_x - L_c(x))

with L the lane's radiance, L_y its radiance after y's emission (x's direct
light and cache terms included), T_x = L_c(x) + rho(x) the terms the estimator
added at x and rho(x) = -n(x, w) f cos / p its residual query (0 after a delta
continuation, whose light L_c leaves out and the path carries). The cache is
evaluated in the loop (deferred.InlineQueries), so each term is known where it
is added; the render frames, deferred and frozen, are not touched.

Why a render of its own and not an extra output of the frames' deferred pass: the
probe is no second path loop (it is the render integrator's ``trace``, through the
hooks above), but it cannot ride on a frame. V_rel is a per-pixel variance of F_r
under one cache, the final one; a frame renders with the cache of its own epoch,
which trains after every frame, and at the default spp of 1 it has one sample per
pixel, no variance. Read off the frames, the samples of a pixel would come from as
many caches as frames. And in the deferred pass L_c(x) is evaluated after the loop,
in the query pass, so the primary hit's terms would have to be kept per lane as
extra outputs of a timed, frozen frame, which the comparison of frame times must
not pay for. One untimed render with ``max(spp, 2)`` samples per pixel and the final
cache gives the variance directly.
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from renderers.integrators import register
from renderers.integrators.cached import CacheState
from renderers.integrators.deferred import InlineQueries, draw_query_key
from renderers.integrators.nirc import NIRCIntegrator
from renderers.integrators.path import Vertex, VertexTerms


class ProbeState(CacheState):
    """The caching state plus what the probe keeps of the primary hit."""

    DRJIT_STRUCT = {
        **CacheState.DRJIT_STRUCT,
        "primary_terms": mi.Spectrum,   # T_x: L_c(x) + rho(x), with the throughput
        "primary_cache": mi.Spectrum,   # L_c(x), with the throughput
        "probed": mi.Bool,              # the primary hit was a cache vertex
        "after_y": mi.Spectrum,         # L_y: the radiance after y's emission
        "reached_y": mi.Bool,           # the path got to y
    }

    def __init__(self, *fields: Any, primary_terms=None, primary_cache=None, probed=None,
                 after_y=None, reached_y=None) -> None:
        super().__init__(*fields)
        self.primary_terms, self.primary_cache, self.probed = primary_terms, primary_cache, probed
        self.after_y, self.reached_y = after_y, reached_y


class DrawRecorder(InlineQueries):
    """In-loop queries that keep the last cache term drawn (L_c of the vertex)."""

    last_drawn: mi.Spectrum | None = None

    def draw(self, handle: Any, count: mi.UInt32, active: mi.Bool) -> mi.Spectrum:
        self.last_drawn = super().draw(handle, count, active)
        return self.last_drawn


@register
class ResidualProbe(NIRCIntegrator):
    """The unbiased NIRC estimator (also SS NIRC's), tracing residual samples (module doc)."""

    plugin_name = "nirc_residual_probe"

    def init_state(self, ray: mi.Ray3f, sampler: mi.Sampler) -> ProbeState:
        base = super().init_state(ray, sampler)
        fields = [getattr(base, name) for name in CacheState.DRJIT_STRUCT]
        return ProbeState(*fields, primary_terms=mi.Spectrum(0), primary_cache=mi.Spectrum(0),
                          probed=mi.Bool(False), after_y=mi.Spectrum(0),
                          reached_y=mi.Bool(False))

    def after_emission(self, vertex: Vertex, state: ProbeState) -> ProbeState:
        state = super().after_emission(vertex, state)
        at_y = vertex.active & (vertex.depth == 1)
        state.after_y = dr.select(at_y, vertex.L, state.after_y)
        state.reached_y |= at_y
        return state

    def vertex_terms(self, vertex: Vertex, state: ProbeState) -> tuple[VertexTerms, ProbeState]:
        before = mi.UInt32(state.cache_vertices)
        terms, state = super().vertex_terms(vertex, state)
        primary = (vertex.depth == 0) & (state.cache_vertices > before)
        state.primary_terms = dr.select(primary, vertex.beta * terms.L_add, state.primary_terms)
        state.primary_cache = dr.select(primary, vertex.beta * self.queries.last_drawn,
                                        state.primary_cache)
        state.probed |= primary
        return terms, state

    def residual_samples(self, scene: mi.Scene, spp: int, seed: int) -> tuple[np.ndarray,
                                                                              np.ndarray]:
        """``spp`` residual samples per pixel: (H, W, spp, 3) values and (H, W, spp) the
        lanes whose primary hit was a cache vertex (elsewhere the value is 0)."""
        sensor = scene.sensors()[0]
        width, height = sensor.film().crop_size()
        lanes = width * height * spp
        sampler = sensor.sampler().fork()
        sampler.set_sample_count(spp)
        sampler.set_samples_per_wavefront(spp)
        sampler.seed(seed, lanes)
        # Pixel-major lanes, as Mitsuba's render lays them out (cached.pixel_index).
        pixel = dr.arange(mi.UInt32, lanes) // spp
        position = mi.Point2f(mi.Float(pixel % width), mi.Float(pixel // width))
        film_uv = (position + sampler.next_2d()) / mi.ScalarVector2f(width, height)
        ray, _ = sensor.sample_ray(0.0, sampler.next_1d(), film_uv, sampler.next_2d())
        self.queries = DrawRecorder(self.cache, self.surface_inputs, self,
                                    draw_query_key(sampler))
        try:
            L, _, _, state = self.trace(scene, sampler, ray)
        finally:
            self.queries = None
        continuation = dr.select(state.reached_y, L - state.after_y, 0)
        residual = dr.select(state.probed,
                             continuation + state.primary_terms - state.primary_cache, 0)
        values = np.array(residual, dtype=np.float64).reshape(3, height, width, spp)
        probed = np.array(state.probed, dtype=bool).reshape(height, width, spp)
        return np.moveaxis(values, 0, -1), probed
