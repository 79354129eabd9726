"""`nirc`: the Neural Incident Radiance Cache in the shared path-tracing core.

The cache n(x, w_i) approximates the *indirect* incident radiance L_ind(x, w_i)
(NIRC paper Eq. 8-9): radiance reflected at the next vertex y toward x, without
y's own emission, which next-event estimation and MIS already account for.
With N_c directions w_i sampled from the *smooth* lobes of the BSDF at x, the
cache term is

    L_c = 1/N_c sum_i n(x, w_i) f_s(x, w_i, w_o) cos / p_s(w_i)          (Eq. 12)

Delta and smooth lobes (e.g. Mitsuba's ``plastic``): the indirect light at x
is I = I_s + I_delta. L_c estimates only I_s (its samples are drawn with a
BSDF context that excludes delta lobes, so f_s and p_s are the smooth part's);
I_delta is never cached: it is estimated by the path itself, which continues
whenever its continuation sample picked a delta lobe (with Mitsuba's weight
F / P_delta, whose expectation over the lobe choice is I_delta). So at a
vertex where the method replaces the smooth indirect light ("stop"), a
smooth continuation only collects its emitter hit and a delta continuation
goes on as a path; the expectation is I_s + I_delta whenever the stop
decision does not depend on the continuation's lobe (SPH, adaptive).

Two estimators use it:

* biased (Eq. 13): at the vertex where the path terminates, L_e + L_nee + L_c,
  in the order of the authors' code: NEE with its MIS weight; sample the
  continuation direction; the continuation ray collects the MIS-weighted
  emission it hits (``VertexTerms.stop_indirect``, path.py); the termination
  decision only replaces the *indirect* part by L_c (N_c fresh samples, not the
  continuation direction), and nothing is divided by the continuation
  probability. So direct light is exactly PT's. Where the path terminates is
  the termination policy's decision (``renderers.integrators.termination``,
  asked at each vertex): the Balanced Termination Heuristic (``bth``, Eq.
  22-23, then the spread heuristic), the spread heuristic alone (``sph``) or
  the per-pixel policy of Sec. 6.3 (``adaptive``: at the first vertex v1 where
  the pixel's v1 mask allows, the mask coming from the relative bias of the
  converged cache-at-v1 image, jobs/sweeps/sweep.py; later by the spread
  heuristic). N_c may differ at v1 and later where the policy takes two values
  (``nc='8,1'``: 8 neural samples at v1, 1 afterwards — the paper's "NIRC
  equal time" series varies the first). BTH is biased even with a perfect
  cache unless L_ind is uniform over the hemisphere: P_s depends on the
  direction the continuing path then follows and the continuing path is not
  reweighted (docs/estimators.md).
* unbiased (Eq. 10-11, two-level Monte Carlo): at the first len(nc) (at most
  three) non-specular vertices (with ``primary_only``, SS NIRC: at the primary
  hit alone, where it is non-specular) add L_c and the residual with the path's own
  continuation direction w, -n(x, w) f cos / p(w) (only where w is a smooth
  sample: a delta continuation estimates I_delta, which L_c leaves out), then
  continue as PT: the path's continuation is the one-sample estimate of
  L_ind(x, w), so the residual term has expectation E[L_ind - n] and the whole
  estimator has exactly PT's expectation, whatever the cache has learned.

The cache term is computed after the path loop, on the cache vertices only
(deferred.py): at a cache vertex the loop records the ray that found it, the
throughput and N_c, and, for the unbiased residual, the continuation
direction with its factor -f cos / p. The deferred pass re-creates the
vertex, draws the N_c smooth directions with their factors f_s cos / (p_s
N_c) (:meth:`NIRCIntegrator.drawn_query`, each from its own random
stream) and evaluates the network on all of them. A lane that never uses the
cache draws nothing for it.
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

import drjit as dr
import mitsuba as mi

from renderers.integrators import register
from renderers.integrators.cached import CachedPathIntegrator, CacheState, smooth_context
from renderers.integrators.deferred import QueryLayout
from renderers.integrators.path import Vertex, VertexTerms
from renderers.integrators.termination import TerminationPolicy, TerminationQuery


class NIRCSettings(Protocol):
    """What the estimator reads of the `nirc` method's validated parameters
    (renderers.methods.nirc.NIRCParams; that module declares this integrator)."""

    estimator: str
    #: Use the cache at the primary hit only (SS NIRC, whose key is the pixel).
    primary_only: bool

    def sample_counts(self) -> list[int]: ...

    def termination_policy(self) -> TerminationPolicy: ...


NIRC_PLUGIN = "nirc_nirc"


@register
class NIRCIntegrator(CachedPathIntegrator):
    """PT core + NIRC cache terms, configured by the `nirc` method's validated
    parameters (:class:`NIRCSettings`, the `nirc` method's model: ``estimator``,
    ``nc``, the termination policy) through :meth:`configure`.

    The plugin's properties are those of the PT core; the estimator's own
    parameters come only through :meth:`configure`, so they are parsed and
    validated once, by the method's model.
    """
    plugin_name = NIRC_PLUGIN

    #: A policy's fractional continuation weight blends L_c with the continuation.
    continuation_weights = True

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.nc: list[int] = []       # N_c per vertex: set by configure
        self.policy: TerminationPolicy | None = None   # of the biased estimator

    def configure(self, params: NIRCSettings) -> None:
        """Take the method's parameters (validated once, by the model)."""
        self.estimator = params.estimator
        self.primary_only = params.primary_only
        self.nc = params.sample_counts()
        self.policy = params.termination_policy()

    def query_layout(self) -> QueryLayout:
        """Unbiased: len(nc) vertices of N_c + 1 queries (the residual), an exact bound.
        Biased: N_c queries at each vertex where the path terminated into the cache."""
        if not self.nc:
            raise RuntimeError("the nirc integrator needs configure(params) before it renders "
                               "(renderers.methods.nirc.build does it)")
        if self.estimator == "unbiased":
            return QueryLayout(len(self.nc), max(self.nc) + 1)
        return QueryLayout(self.vertex_slots, max(self.nc))

    # ---- Cache term L_c over the smooth lobes (Eq. 12): the queries a vertex draws ----
    @property
    def drawn_slots(self) -> int:
        return max(self.nc)

    def drawn_query(self, si: mi.SurfaceInteraction3f, bsdf: mi.BSDF, rng: mi.PCG32,
                    slot: mi.UInt32, count: mi.UInt32) -> tuple[mi.Vector3f, mi.Spectrum, mi.Bool]:
        """L_c = 1/N_c sum_i n(x, w_i) f_s cos / p_s: query i = ``slot`` of the N_c =
        ``count`` of a vertex, a fresh smooth sample w_i with the factor f_s cos /
        (p_s N_c). Called by the deferred pass on the recorded vertices (deferred.py)."""
        use = slot < count
        u1 = rng.next_float32(use)
        u2 = mi.Point2f(rng.next_float32(use), rng.next_float32(use))
        bs, weight = bsdf.sample(smooth_context(), si, u1, u2, use)
        return (si.to_world(bs.wo), weight * dr.rcp(mi.Float(dr.maximum(count, 1))),
                use & (bs.pdf > 0))

    def residual_weight(self, vertex: Vertex) -> mi.Spectrum:
        """The factor of n(x, w) in the residual along the continuation w (Eq. 11): -f cos / p."""
        return -vertex.bsdf_weight

    def vertex_terms(self, vertex: Vertex, state: CacheState) -> tuple[VertexTerms, CacheState]:
        smooth = mi.has_flag(vertex.bsdf.flags(), mi.BSDFFlags.Smooth)
        usable = vertex.active_next & smooth
        if self.estimator == "unbiased":
            return self._unbiased_terms(vertex, state, usable)
        return self._biased_terms(vertex, state, usable)

    def _unbiased_terms(self, vertex: Vertex, state: CacheState,
                        usable: mi.Bool) -> tuple[VertexTerms, CacheState]:
        # ---- Two-level MC (Eq. 10-11): L_c plus the residual along the continuation ----
        use = usable & (state.cache_vertices < len(self.nc))
        if self.primary_only:
            use &= vertex.depth == 0
        nc_lane = mi.UInt32(self.nc[-1])
        for index in reversed(range(len(self.nc) - 1)):
            nc_lane = dr.select(state.cache_vertices == index, self.nc[index], nc_lane)
        handle = self.queries.vertex(state.cache_vertices, vertex, use)
        L_c = self.queries.draw(handle, nc_lane, use)
        # The continuation sample was drawn independently of the N_c cache samples;
        # only a smooth one estimates what L_c integrates (I_s).
        bs = vertex.bsdf_sample
        smooth_cont = use & (bs.pdf > 0) & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        residual = self.queries.add(handle, max(self.nc), vertex.si.to_world(bs.wo),
                                    self.residual_weight(vertex), smooth_cont)
        state.cache_vertices = dr.select(use, state.cache_vertices + 1, state.cache_vertices)
        terms = VertexTerms(L_add=dr.select(use, L_c + residual, 0), stop=mi.Bool(False),
                            stop_indirect=mi.Bool(False), skip_nee=mi.Bool(False))
        return terms, state

    def _biased_terms(self, vertex: Vertex, state: CacheState,
                      usable: mi.Bool) -> tuple[VertexTerms, CacheState]:
        # ---- Termination of the smooth indirect part: the policy's decision
        #      (termination/: BTH Eq. 22-23, SPH Eq. 19-21, adaptive Sec. 6.3). NEE
        #      (MIS-weighted) and the continuation's emitter hit are collected
        #      whatever is decided here (path.py, stop_indirect) ----
        weight, state = self.policy.continuation(
            TerminationQuery(vertex, state, usable, self.cache))
        cached = (weight < 1) & usable
        # ---- Shade the vertex: L_e (done) + L_nee (core) + (1 - alpha) L_c (Eq. 13); a
        #      weight alpha > 0 blends with the continuation, which the core weights
        #      alpha from the next vertex's direct light on (VertexTerms.continue_weight) ----
        keep = 1.0 - weight
        nc_at_v1, nc_later = self.policy.settings.nc
        nc_lane = dr.select(vertex.depth == 0, mi.UInt32(nc_at_v1), mi.UInt32(nc_later))
        handle = self.queries.vertex(state.cache_vertices,
                                     dataclasses.replace(vertex, beta=vertex.beta * keep), cached)
        L_c = self.queries.draw(handle, nc_lane, cached)
        # A delta continuation carries I_delta, which L_c leaves out: it goes on as a path,
        # unweighted.
        delta_cont = mi.has_flag(vertex.bsdf_sample.sampled_type, mi.BSDFFlags.Delta)
        stop = cached & (weight <= 0)
        state.cache_depth = dr.select(stop, vertex.depth + 1, state.cache_depth)
        state.cache_vertices = dr.select(cached, state.cache_vertices + 1, state.cache_vertices)
        terms = VertexTerms(L_add=dr.select(cached, L_c * keep, 0), stop=mi.Bool(False),
                            stop_indirect=stop & ~delta_cont, skip_nee=mi.Bool(False),
                            continue_weight=dr.select(cached & ~stop & ~delta_cont, weight, 1.0))
        return terms, state


# ---- Registration (per Mitsuba variant: the `nirc` method calls it when a render starts) ----
