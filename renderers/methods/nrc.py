"""`nrc`: Neural Radiance Cache [MRNK21], terminated by the spread heuristic.

The estimator is in renderers/integrators/nrc.py; the frame loop with online
training in renderers/methods/cached.py. Departure from DESIGN.md: training
targets come from full path-traced training paths (unbiased targets), not from
NRC's self-training with a 1/16 unterminated fraction — the same training
paths serve NIRC and NRC, so the two caches see identical data.
"""

from __future__ import annotations

from typing import Any

from renderers.methods.cached import (
    CacheTrainingParams,
    cached_render,
    load_integrators,
    make_cache,
)


class NRCParams(CacheTrainingParams):
    """Parameters of the `nrc` method (PT core and training parameters included)."""


def build(scene: Any, params: NRCParams, seed: int) -> tuple[Any, Any, Any]:
    """(render integrator, training integrator, cache) of an NRC render."""
    from renderers.caches import nrc_config
    from renderers.integrators import nrc

    integrator, trainer = load_integrators(nrc.NRC_PLUGIN, nrc.NRCIntegrator, params,
                                           key_vertex="arrival")
    return integrator, trainer, make_cache(scene, nrc_config, params, seed)


render = cached_render(build)
