"""`neural-di`: direct light at primary hits as unshadowed terms x cached visibility.

Neural Visibility Cache paper, Sec. 3.1.1 ("Neural DI"): the `nvc-lights`
network and training (renderers.methods.nvc_lights.train_frame: one Adam step
per frame on shadow rays from ``world_points`` + ``camera_points`` positions to
every light), but no light is sampled and no shadow ray is cast for the image:

    L = L_e(x) + Σ_k U_k(x) V_k(x)

at each camera ray's first hit x, U_k the closed-form unshadowed direct light
of polygonal emitter k (exact for diffuse BSDFs; renderers.integrators.
polygon_lights) and V_k the cache's prediction. Biased (docs/estimators.md,
"neural-di"), noise-free but for the pixel footprint. Parameters: those of
renderers.methods.primary, the cache preset ``renderers.caches.visibility_config``
with one output per emitter.

Applies to scenes whose emitters are 1 to 32 polygonal area emitters (one
cache output per light; a closed form per polygon).
"""

from __future__ import annotations

from typing import Any

from renderers.methods import register
from renderers.methods.base import Knob, Method, fixed_stages
from renderers.methods.nvc_lights import (
    MAX_LIGHTS,
    one_output_visibility_config,
    train_frame,
    visibility_cache,
    visibility_cache_render,
)
from renderers.methods.primary import PrimaryCacheParams, lit_surface
from renderers.methods.pt import SPP_CANDIDATES


class NeuralDIParams(PrimaryCacheParams):
    """The cache's training (renderers.methods.primary); the estimator has no parameter."""

    def cache_presets(self) -> dict[str, Any]:
        return {"cache": one_output_visibility_config}


def build(scene: Any, params: NeuralDIParams, seed: int) -> tuple[Any, Any]:
    """(integrator, visibility cache): the primary-hit estimator over an untrained cache."""
    import mitsuba as mi

    from renderers.integrators import register_plugins
    from renderers.integrators.neural_di import PLUGIN_NAME, CacheVisibility

    register_plugins()
    integrator = mi.load_dict({"type": PLUGIN_NAME})
    integrator.lights(scene.scene)  # a scene it cannot shade fails here, before training
    cache = visibility_cache(scene, params, seed, len(scene.scene.emitters()))
    return integrator.with_visibility(CacheVisibility(cache)), cache


render = visibility_cache_render(build, train_frame)


def applies(features: Any) -> tuple[bool, str]:
    """A surface, and 1 to 32 emitters, all polygonal area emitters."""
    applies_, reason = lit_surface(features)
    if not applies_:
        return applies_, reason
    if features.emitter_count > MAX_LIGHTS:
        return False, f"more than {MAX_LIGHTS} emitters: one cache output per light"
    if features.polygon_emitter_count < features.emitter_count:
        return False, ("an emitter that is not a polygon (environment, delta or curved "
                       "area light): neural-di's unshadowed term is a polygon integral")
    return True, ""


METHOD = register(Method("neural-di",
                "neural DI: closed-form unshadowed polygon light x visibility-cache "
                "prediction, no shadow rays (biased): direct light at primary hits only "
                "(max_depth 2)",
                NeuralDIParams, render, version=2, requires=applies,
                label="Neural DI", knob=Knob("spp", SPP_CANDIDATES), unbiased=False,
                stage_sizes=fixed_stages("training_paths", "training")))
