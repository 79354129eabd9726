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

from renderers.methods.cached import (
    CacheTrainingParams,
    cached_render,
    load_integrators,
    make_cache,
)


class NRCParams(CacheTrainingParams):
    """Parameters of the `nrc` method (PT core and training parameters included)."""

    termination: Literal["sph", "adaptive"] = Field(
        "sph", description="spread heuristic, or adaptive (v1 mask, then SPH; Sec. 6.3)")
    self_training: bool = True
    unbiased_every: int = Field(16, ge=1, le=1 << 16,
                                description="every n-th training path is not terminated")


def build(scene: Any, params: NRCParams, seed: int) -> tuple[Any, Any, Any]:
    """(render integrator, training integrator, cache) of an NRC render."""
    from renderers.caches import nrc_config
    from renderers.integrators import nrc

    self_training = {"trainer_cls": nrc.NRCSelfTrainingIntegrator,
                     "trainer_properties": {"unbiased_every": params.unbiased_every,
                                            "sph_c": params.sph_c}}
    integrator, trainer = load_integrators(nrc.NRC_PLUGIN, nrc.NRCIntegrator, params,
                                           key_vertex="arrival",
                                           termination=params.termination,
                                           **(self_training if params.self_training else {}))
    return integrator, trainer, make_cache(scene, nrc_config, params, seed)


render = cached_render(build)
