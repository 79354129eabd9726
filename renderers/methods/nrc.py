"""`nrc`: Neural Radiance Cache [MRNK21], terminated by the spread heuristic.

The estimator is in renderers/integrators/nrc.py; the frame loop with online
training in renderers/methods/cached.py. Training paths use NRC's
self-training by default (they terminate into the cache by the spread
heuristic, except every ``unbiased_every``-th path, 1/16 as in NRC);
``self_training=False`` trains on full path-traced training paths instead, the
same unbiased data NIRC trains on.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from renderers.integrators.termination import policy_names, termination_params_type
from renderers.methods import register
from renderers.methods.base import ComparisonRun, Method, SweepRole
from renderers.methods.cached import (
    ADAPTIVE_EQUAL_BIAS,
    CacheTrainingParams,
    TerminationChoice,
    cached_render,
    has_surface,
    load_integrators,
    make_cache,
    scale_training_floors,
    termination_params_field,
    training_stage_sizes,
)

#: The termination policies of NRC's cache of outgoing radiance (the registry's).
OutgoingTermination = Literal[policy_names("outgoing")]  # type: ignore[valid-type]
OutgoingTerminationParams = termination_params_type("outgoing")


class NRCParams(CacheTrainingParams, TerminationChoice):
    """Parameters of the `nrc` method (PT core and training parameters included)."""

    termination: OutgoingTermination = Field(
        "sph", description="termination policy (renderers/integrators/termination)")
    termination_params: OutgoingTerminationParams = termination_params_field()
    self_training: bool = Field(
        True, description="NRC's self-training (paths end in the cache, every "
                          "unbiased_every-th one traced in full); false: full paths only")
    unbiased_every: int = Field(16, ge=1, le=1 << 16,
                                description="every n-th training path is not terminated")

    def cache_presets(self) -> dict[str, Any]:
        from renderers.caches.config import nrc_config

        return {"cache": nrc_config}


def build(scene: Any, params: NRCParams, seed: int) -> tuple[Any, Any, Any]:
    """(render integrator, training integrator, cache) of an NRC render."""
    from renderers.integrators import nrc, register_plugins

    register_plugins()
    trainer = (nrc.NRCSelfTrainingIntegrator.plugin_name
               if params.self_training else None)
    integrator, trainer = load_integrators(nrc.NRC_PLUGIN, params, key_vertex="arrival",
                                           trainer_plugin=trainer)
    return integrator, trainer, make_cache(scene, params.cache_config(), seed)


METHOD = register(Method(
    "nrc", "Neural Radiance Cache, spread-angle termination", NRCParams, cached_render(build),
    version=3,
    sweep=SweepRole("NRC", ADAPTIVE_EQUAL_BIAS), build=build, requires=has_surface, label="NRC", unbiased=False,
    stage_sizes=training_stage_sizes, scale_floors=scale_training_floors,
    comparison=(ComparisonRun(2, "NRC", "NRC biased", role="matched"),)))
