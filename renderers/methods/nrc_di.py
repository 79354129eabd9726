"""`nrc-di`: a neural cache of the direct light at primary hits (NVC paper's NRC DI).

Neural Visibility Cache paper, Sec. 4.2: the visibility cache's network with
three outputs (``renderers.caches.direct_light_config``) caches the RGB direct
light reflected at a position, trained online (one Adam step per frame) on
one-sample NEE estimates at ``camera_points`` camera first hits and
``world_points`` surface points reached from the scene's box
(renderers.integrators.nrc_di); the image is the prediction at each camera
ray's first hit plus the emission seen there. Biased, noise-free but for the
pixel footprint (docs/estimators.md, "nrc-di"). Parameters: those of
renderers.methods.primary.

Applies to scenes with a surface and an emitter (any kind, any number).
"""

from __future__ import annotations

from typing import Any

from renderers.methods import register
from renderers.methods.base import Knob, Method, fixed_stages
from renderers.methods.cached import make_cache
from renderers.methods.nvc_lights import train_frame, visibility_cache_render
from renderers.methods.primary import PrimaryCacheParams, lit_surface
from renderers.methods.pt import SPP_CANDIDATES


class NRCDIParams(PrimaryCacheParams):
    """The cache's training (renderers.methods.primary)."""

    def cache_presets(self) -> dict[str, Any]:
        from renderers.caches.config import direct_light_config

        return {"cache": direct_light_config}


def build(scene: Any, params: NRCDIParams, seed: int) -> tuple[Any, Any]:
    """(integrator, RGB cache): the prediction at first hits, untrained."""
    import mitsuba as mi

    from renderers.integrators import register_plugins
    from renderers.integrators.nrc_di import PLUGIN_NAME, DirectLightRecords

    register_plugins()
    cache = make_cache(scene, params.cache_config(), seed)
    # Its frame's training records, frozen where freezing is on (what train_frame reads).
    cache.training_records = DirectLightRecords(params.world_points, params.camera_points)
    return mi.load_dict({"type": PLUGIN_NAME}).with_cache(cache), cache


render = visibility_cache_render(build, train_frame)


METHOD = register(Method("nrc-di",
                "NRC DI: a hash-grid + 2x32 MLP cache of the direct light, trained online "
                "on one-sample NEE, rendered as its prediction (biased): primary hits only "
                "(max_depth 2)",
                NRCDIParams, render, version=2,
                requires=lit_surface, label="NRC DI", knob=Knob("spp", SPP_CANDIDATES), unbiased=False,
                stage_sizes=fixed_stages("training_paths", "training")))
