"""`ss-nirc`: screen-space NIRC (NIRC paper Sec. 6.1, Fig. 6), unbiased.

NIRC whose position input is one trainable latent vector per film pixel
(renderers.caches.screen: 74 floats by default, the paper's equal-memory preset
beside the control variates' 75) instead of the hash grid, with 6 hidden layers
(renderers.caches.config.ss_nirc_config). The key of a shading point is the pixel
it projects to, which is the pixel of the path only at the primary hit, so the
cache serves the primary hit alone:

* render: the two-level estimator (Eq. 10-12) at the primary hit when it is
  non-specular, L_c from ``nc`` cache samples plus the residual along the path's
  own continuation; every deeper vertex is plain PT (no cache term). A delta
  primary hit is plain PT throughout. Unbiased whatever the latent vectors hold.
* training: records at the primary hit only (``record_depth`` 1), from training
  paths that start at random film positions like NIRC's.

The latent table holds ``features`` floats per pixel (what the cache is); Adam's
two moments and the weight EMA add three more per feature while it trains. A run
stores both (``method_stats["model"]["floats_per_pixel"]``, as the control-variate
methods do).
"""

from __future__ import annotations

from typing import Any, ClassVar

from pydantic import Field

from renderers.methods import register
from renderers.methods.base import Method, RenderOutput
from renderers.methods.cached import (
    CacheTrainingParams,
    cached_render,
    has_surface,
    load_integrators,
    scale_training_floors,
    training_stage_sizes,
)

#: Floats per latent float while training: Adam's two moments and the weight EMA.
TRAINING_COPIES = 3


class SSNIRCParams(CacheTrainingParams):
    """Parameters of `ss-nirc` (PT core and training parameters included); the latent
    size is the cache override ``cache.screen_latent.features``."""

    #: Read by the NIRC integrator (renderers.integrators.nirc.NIRCSettings).
    estimator: ClassVar[str] = "unbiased"
    primary_only: ClassVar[bool] = True

    nc: int = Field(3, ge=1, le=256, description="N_c: cache samples at the primary hit")
    record_depth: int = Field(1, ge=1, le=1,
                              description="vertices recorded per training path: the "
                                          "primary hit only (its pixel is its key)")

    def cache_presets(self) -> dict[str, Any]:
        from renderers.caches.config import ss_nirc_config

        return {"cache": ss_nirc_config}

    def sample_counts(self) -> list[int]:
        return [self.nc]

    def termination_policy(self) -> None:
        """The unbiased estimator terminates nothing into the cache."""
        return None


def floats_per_pixel(config: Any) -> dict[str, int]:
    """The latent floats per pixel (``model``) and what training keeps besides them."""
    features = config.screen_latent.features
    return {"model": features, "training": TRAINING_COPIES * features}


def build(scene: Any, params: SSNIRCParams, seed: int) -> tuple[Any, Any, Any]:
    """(render integrator, training integrator, cache) of an SS NIRC render."""
    from renderers.caches import NeuralCache
    from renderers.caches.screen import ScreenProjection
    from renderers.integrators import nirc, register_plugins

    register_plugins()
    integrator, trainer = load_integrators(nirc.NIRC_PLUGIN, params, key_vertex="departure")
    bbox = scene.scene.bbox()
    cache = NeuralCache(params.cache_config(), list(bbox.min), list(bbox.max), seed=seed,
                        screen=ScreenProjection(scene.scene.sensors()[0]))
    return integrator, trainer, cache


def render(scene: Any, params: SSNIRCParams, **loop: Any) -> RenderOutput:
    """NIRC's frame loop (renderers.methods.cached), with the memory per pixel stored."""
    output = cached_render(build)(scene, params, **loop)
    output.method_stats["model"] = {"floats_per_pixel": floats_per_pixel(params.cache_config())}
    return output


METHOD = register(Method(
    "ss-nirc", "screen-space NIRC: one latent vector per pixel instead of the hash grid, "
               "6 layers, two-level Monte Carlo at the primary hits (unbiased)",
    SSNIRCParams, render, version=1, build=build, requires=has_surface, label="SS NIRC",
    stage_sizes=training_stage_sizes, scale_floors=scale_training_floors, unbiased=True))
