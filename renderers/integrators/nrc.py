"""`nrc`: the Neural Radiance Cache [MRNK21] in the shared path-tracing core.

The cache approximates the radiance *reflected* at a vertex toward w_o,
L_r(x, w_o) (direct light included; the vertex's own emission is added by the
path before), albedo-demodulated: the network predicts L_r / (a_d + a_s) and the
query multiplies by a_d + a_s, so it learns the smoother irradiance-like part.

A path terminates into the cache at the first vertex where the spread heuristic
fires (NIRC paper Eq. 19-21 in NRC's original form, spread.py); there it adds
beta * cache(x, w_o) and, since the cache already contains direct light, does
no next-event estimation and ends without tracing its continuation
(``VertexTerms.stop``; NIRC's ``stop_indirect`` would count the continuation's
emitter hit twice). Vertices whose BSDF has no smooth lobe (mirrors, glass)
never terminate. The decision does not look at the lobe the continuation
sample picked: L_r contains the light of every lobe, delta lobes included, so
continuing only where a delta lobe was sampled would bias it. One cache query
per path, as
in the NIRC paper's NRC baseline (Sec. 6.2); the render integrator records it
in the loop and evaluates it after (deferred.py; the buffer bound is exact:
one query per lane). Training uses NRC's self-training
(``NRCSelfTrainingIntegrator``) by default, whose paths evaluate the query in
the loop (their targets need its value there).
"""

from __future__ import annotations

from functools import partial
from typing import Any, Protocol

import drjit as dr
import mitsuba as mi

from renderers.integrators import register
from renderers.integrators.cached import (
    CachedPathIntegrator,
    CacheState,
    cache_inputs,
    demodulation,
    new_cache_state,
    update_spread,
)
from renderers.integrators.deferred import InlineQueries, QueryBuffer, QueryLayout
from renderers.integrators.path import Vertex, VertexTerms
from renderers.integrators.termination import (
    TerminationPolicy,
    TerminationQuery,
    TerminationSettings,
    make_policy,
    policy_params,
)
from renderers.integrators.training import TRAINING_PLUGIN, TrainingPathIntegrator


class NRCSettings(Protocol):
    """What the estimator and its self-training paths read of the `nrc` method's
    validated parameters (renderers.methods.nrc.NRCParams; that module declares
    these integrators)."""

    unbiased_every: int

    def termination_policy(self) -> TerminationPolicy: ...

    def termination_settings(self) -> TerminationSettings: ...


NRC_PLUGIN = "nirc_nrc"
#: NRC is not used at v1 on surfaces glossier than this (NIRC paper Sec. 6.3).
MIN_V1_ROUGHNESS = 0.0625


def nrc_terms(queries: QueryBuffer | InlineQueries, policy: TerminationPolicy | None,
              vertex: Vertex, state: CacheState, may_terminate: mi.Bool | bool = True,
              cache: Any = None) -> tuple[VertexTerms, CacheState]:
    """Terminate into the outgoing-radiance cache (see module doc) where ``policy``
    says so (termination/: the spread heuristic, never at the first vertex; or
    adaptive, NIRC paper Sec. 6.3, at v1 where the pixel's v1 mask allows). At v1
    the cache is not used on surfaces glossier than ``MIN_V1_ROUGHNESS``. The query
    goes to ``queries`` (deferred, or evaluated in the loop for training paths)."""
    if policy is None:
        raise RuntimeError("the nrc integrators need configure(params) before they trace "
                           "(renderers.methods.nrc.build does it)")
    smooth = mi.has_flag(vertex.bsdf.flags(), mi.BSDFFlags.Smooth)
    inputs = cache_inputs(vertex.si, vertex.bsdf, specular=True)
    usable = vertex.active_next & smooth & may_terminate
    weight, state = policy.continuation(TerminationQuery(vertex, state, usable, cache))
    stop = (weight < 1) & ((vertex.depth > 0) | (inputs["roughness"] >= MIN_V1_ROUGHNESS))
    stop &= usable
    # ---- Shade the terminal vertex with the cache: L_e (done) + L_r(x, w_o) ----
    handle = queries.vertex(state.cache_vertices, vertex, stop, inputs)
    L_r = queries.add(handle, 0, -vertex.ray.d, demodulation(inputs), stop)
    state.cache_depth = dr.select(stop, vertex.depth + 1, state.cache_depth)
    state.cache_vertices = dr.select(stop, state.cache_vertices + 1, state.cache_vertices)
    terms = VertexTerms(L_add=dr.select(stop, L_r, 0), stop=stop,
                        stop_indirect=mi.Bool(False), skip_nee=stop)
    return terms, state


def self_training_policy(params: NRCSettings) -> TerminationPolicy:
    """The spread heuristic (``sph``) that ends NRC's self-training paths, whatever
    policy the render paths use."""
    return make_policy(policy_params("sph"), params.termination_settings())


def refuse_blending(policy: TerminationPolicy) -> TerminationPolicy:
    """``policy``, if its decisions only stop or continue (NRC's cache ends the path)."""
    if policy.blends:
        raise ValueError(f"nrc stops or continues; termination {policy.name!r} blends the "
                         "cache with the next segment")
    return policy


@register
class NRCIntegrator(CachedPathIntegrator):
    """PT core + termination into an outgoing-radiance cache.

    The termination policy (termination/) comes from the method's model
    (:class:`NRCSettings`) through :meth:`configure`, which must come first.
    """
    plugin_name = NRC_PLUGIN

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.policy: TerminationPolicy | None = None   # set by configure

    def configure(self, params: NRCSettings) -> None:
        """Take the `nrc` method's parameters (validated once, by the model)."""
        self.policy = refuse_blending(params.termination_policy())

    def query_layout(self) -> QueryLayout:
        """One query per lane, an exact bound: the path ends where it queries."""
        return QueryLayout(1, 1)

    def surface_inputs(self, si: mi.SurfaceInteraction3f, bsdf: mi.BSDF) -> dict[str, Any]:
        """NRC's cache inputs: with the specular albedo."""
        return cache_inputs(si, bsdf, specular=True)

    def vertex_terms(self, vertex: Vertex, state: CacheState) -> tuple[VertexTerms, CacheState]:
        return nrc_terms(self.queries, self.policy, vertex, state, cache=self.cache)


@register
class NRCSelfTrainingIntegrator(TrainingPathIntegrator):
    """NRC's self-training paths [MRNK21]: training paths that terminate into the cache.

    Training paths are terminated by the spread heuristic (``sph``), as render paths
    and end with the cache's own prediction, so targets are cheap and
    low-variance but biased toward the cache; a fraction ``1/unbiased_every``
    of them (1/16 in NRC) never terminates and keeps the cache anchored to
    path-traced radiance. A record *at* a terminal vertex would have the cache's
    own output as its target, so it is invalidated. Records are keyed at the
    arrival vertex (``key_vertex='arrival'``), as NRC caches outgoing radiance.
    """
    plugin_name = f"{TRAINING_PLUGIN}_nrcselftrainingintegrator"

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.unbiased_every = int(props.get("unbiased_every", 16))
        self.spread: TerminationPolicy | None = None   # set by configure
        self.cache: Any = None
        if self.key_vertex != "arrival":
            raise ValueError("NRC self-training records at the arrival vertex")
        if self.unbiased_every < 1:
            raise ValueError("unbiased_every must be >= 1")

    def configure(self, params: NRCSettings) -> None:
        """Take the `nrc` method's parameters (validated once, by the model)."""
        self.unbiased_every = params.unbiased_every
        self.spread = self_training_policy(params)

    def frame_freezable(self) -> bool:
        """The core's condition, and the cache hands over what its queries read."""
        return super().frame_freezable() and hasattr(self.cache, "inference_state")

    def frame_state(self, scene: mi.Scene) -> dict[str, Any]:
        """The core's, and the cache's inference weights (the paths query the cache)."""
        cache = self.cache.inference_state() if hasattr(self.cache, "inference_state") else None
        return {**super().frame_state(scene), "cache": cache}

    def bind_frame_state(self, scene: mi.Scene, state: dict[str, Any]) -> None:
        super().bind_frame_state(scene, state)
        if state["cache"] is not None:
            self.cache.bind_inference(state["cache"])

    def init_state(self, ray: mi.Ray3f, sampler: mi.Sampler) -> CacheState:
        return new_cache_state()

    def after_emission(self, vertex: Vertex, state: CacheState) -> CacheState:
        return update_spread(vertex, super().after_emission(vertex, state))

    def vertex_terms(self, vertex: Vertex, state: CacheState) -> tuple[VertexTerms, CacheState]:
        _, state = super().vertex_terms(vertex, state)
        may_terminate = self.path_index() % self.unbiased_every != 0
        terms, state = nrc_terms(InlineQueries(self.cache, partial(cache_inputs, specular=True)),
                                 self.spread, vertex, state, may_terminate, self.cache)
        own_prediction = terms.stop & (vertex.depth < self.record_depth)
        dr.scatter(self.buffers["valid"], False, self._slot(vertex.depth), own_prediction)
        return terms, state


# ---- Registration (per Mitsuba variant: the `nrc` method calls it when a render starts) ----
