"""`nirc-nvc-env`: NIRC for indirect light, the environment's visibility cache for
its direct light (NIRC paper Sec. 4 and 5 together).

The estimate at a vertex x is the sum of three independent parts:

* other emitters' NEE and every BSDF-sampled emitter hit: the PT core's, with
  MIS weights computed with the full selector pdf (path.py);
* the environment's NEE, I_env(x): :class:`~renderers.integrators.nvc_env.EnvVisibility`,
  N_c env-map directions weighted by the visibility cache (+ the one-shadow-ray
  residual when ``env_estimator='unbiased'``; NIRC Eq. 10-12 with V L_env as
  the cached quantity). The core's selector drops its environment samples
  (:class:`~renderers.integrators.nvc_env.WithoutEnvironmentNEE`);
* indirect light: NIRC's cache terms, biased (Eq. 13, termination into the
  cache) or unbiased (Eq. 10-11), exactly as in nirc.py. The NIRC cache
  learns L_ind(x, w), the radiance the next vertex y sends toward x without
  y's own emission; an escaped ray's environment radiance is emission, so it
  is not in L_ind, and I_env at y (direct light at y, indirect at x) is in it.

Each part has the expectation of the corresponding part of PT where its
estimator is unbiased, so the combination is unbiased when both are; where
NIRC terminates into its cache (biased), the environment term is still
computed at the terminal vertex, as the core's NEE is.

Two caches, two query channels (deferred.py): NIRC's queries are counted by
``CacheState.cache_vertices``, the environment's by ``env_vertices``; each
frame records both and evaluates each after the loop on its used queries.
"""

from __future__ import annotations

from typing import Any

import mitsuba as mi

from renderers.integrators import register
from renderers.integrators.cached import CacheState
from renderers.integrators.nirc import NIRCIntegrator
from renderers.integrators.nvc_env import (
    EnvVisibility,
    NVCEnvSettings,
    WithoutEnvironmentNEE,
    only_environment,
)
from renderers.integrators.path import Vertex, VertexTerms

NIRC_NVC_ENV_PLUGIN = "nirc_nirc_nvc_env"


@register
class NIRCEnvIntegrator(NIRCIntegrator):
    """NIRC's integrator whose environment NEE is nvc-env's (module docstring)."""
    plugin_name = NIRC_NVC_ENV_PLUGIN

    light_sampler_type = WithoutEnvironmentNEE

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.env: EnvVisibility | None = None   # set by configure_env

    def configure_env(self, params: NVCEnvSettings, cache: Any) -> None:
        """The environment term's parameters and its (visibility) cache."""
        self.env = EnvVisibility(params, cache, self.max_depth, counter="env_vertices")

    def query_channels(self) -> list[Any]:
        if self.env is None:
            raise RuntimeError("the nirc-nvc-env integrator needs configure_env(params, "
                               "cache) (renderers.methods.nirc_nvc_env.build does it)")
        return [self, self.env]

    def vertex_terms(self, vertex: Vertex, state: CacheState) -> tuple[VertexTerms, CacheState]:
        terms, state = super().vertex_terms(vertex, state)
        terms.L_add = terms.L_add + self.env.terms(vertex, state, self.light_sampler(vertex.scene))
        terms.skip_nee = only_environment(vertex.scene)
        return terms, state


# ---- Registration (per Mitsuba variant: the method calls it when a render starts) ----
