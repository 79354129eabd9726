"""Neural direct illumination (`neural-di`): the visibility cache's weights as the image.

Neural Visibility Cache paper (Bokšanský & Meister), Sec. 3.1.1: the light
weights of the NVC's light selection are the unshadowed contribution of each
light times its predicted visibility; summed over the lights they are an
approximation of the direct light that needs no shadow ray:

    D(x, ω_o) = Σ_k U_k(x, ω_o) · V_k(x)

U_k the closed-form unshadowed term of polygonal emitter k
(renderers.integrators.polygon_lights: exact for diffuse BSDFs), V_k(x) in
[0, 1] the visibility of light k from x the cache predicts (the `nvc-lights`
network and training, renderers.integrators.nvc_lights). Biased, and noise-free
but for the pixel footprint: nothing in D is sampled.

Even with exact visibility the product is an approximation: the cache learns
the *area-averaged* visibility V̄_k(x) (its training targets are shadow rays
to uniform points on the light), while the direct light weights the
visibility by the light's cosine-weighted solid angle,

    ∫_k f L_e G V dA  =  U_k · V̄_k   only where V is constant over light k
                                      (fully visible or fully hidden),

so penumbrae carry a bias of their own (docs/estimators.md, "neural-di").
:class:`TracedVisibility` estimates V̄_k with shadow rays (an oracle cache:
what a perfectly trained network predicts), which separates that bias from
the network's.
"""

from __future__ import annotations

from typing import Any, Protocol

import drjit as dr
import mitsuba as mi

from renderers.integrators import register
from renderers.integrators.polygon_lights import PolygonLights
from renderers.integrators.primary import PrimaryHitIntegrator

PLUGIN_NAME = "nirc_neural_di"


class Visibility(Protocol):
    """V_k(x) of every light k at the first hits ``si`` (a list of Floats, one per emitter)."""

    def __call__(self, scene: mi.Scene, sampler: mi.Sampler, si: mi.SurfaceInteraction3f,
                 active: mi.Bool) -> list[mi.Float]: ...

    def frame_state(self) -> dict[str, Any]:
        """The Dr.Jit data the visibility reads (renderers.frozen)."""
        ...

    def bind(self, state: dict[str, Any]) -> None: ...


class CacheVisibility:
    """V_k(x) from a visibility cache: its sigmoid outputs at x (one per emitter)."""

    def __init__(self, cache: Any) -> None:
        self.cache = cache

    def __call__(self, scene, sampler, si, active):
        return self.cache.query_outputs(self.cache.surface_features(si.p))

    def frame_state(self) -> dict[str, Any]:
        return self.cache.inference_state()

    def bind(self, state: dict[str, Any]) -> None:
        self.cache.bind_inference(state)


class TracedVisibility:
    """V̄_k(x) estimated with ``rays`` shadow rays per light toward points the emitter
    samples (``sample_direction``: uniform on a polygon's area), the cache's training
    target (renderers.integrators.nvc_lights.visibility_records) at the shading point:
    an unbiased estimate of what a perfect visibility cache predicts."""

    def __init__(self, rays: int = 1) -> None:
        if rays < 1:
            raise ValueError("TracedVisibility needs at least one ray per light")
        self.rays = rays

    def frame_state(self) -> dict[str, Any]:
        return {}

    def bind(self, state: dict[str, Any]) -> None:
        """Nothing to read: the shadow rays see the scene."""

    def __call__(self, scene, sampler, si, active):
        values = []
        for emitter in scene.emitters():
            seen = mi.Float(0)
            for _ in range(self.rays):
                ds, weight = emitter.sample_direction(si, sampler.next_2d(active), active)
                ok = active & (ds.pdf > 0) & (dr.max(mi.unpolarized_spectrum(weight)) > 0)
                ok &= ~scene.ray_test(si.spawn_ray_to(ds.p), ok)
                seen += dr.select(ok, 1.0, 0.0)
            values.append(seen / self.rays)
        return values


@register
class NeuralDIIntegrator(PrimaryHitIntegrator):
    """D(x) = Σ_k U_k(x) V_k(x) at the first hit (module docstring).

    ``visibility`` (a :class:`Visibility`) must be set on the loaded instance
    (:meth:`with_visibility`) before rendering; the polygon lights are built once
    per scene.
    """
    plugin_name = PLUGIN_NAME

    visibility: Visibility | None = None

    def with_visibility(self, visibility: Visibility) -> NeuralDIIntegrator:
        self.visibility = visibility
        return self

    def lights(self, scene: mi.Scene) -> PolygonLights:
        cached = getattr(self, "_lights", None)
        if cached is None or cached.scene is not scene:
            cached = self._lights = PolygonLights(scene)
        return cached

    def frame_state(self, scene: mi.Scene) -> dict[str, Any]:
        return {"lights": self.lights(scene).frame_arrays(),
                "visibility": self._visibility().frame_state()}

    def bind_frame_state(self, scene: mi.Scene, state: dict[str, Any]) -> None:
        self.lights(scene).bind(state["lights"])
        self._visibility().bind(state["visibility"])

    def _visibility(self) -> Visibility:
        if self.visibility is None:
            raise ValueError("NeuralDIIntegrator needs a visibility source: "
                             "call with_visibility(CacheVisibility(cache)) first")
        return self.visibility

    def direct(self, scene, sampler, si, active):
        return self.lights(scene).shade(si, self._visibility()(scene, sampler, si, active),
                                        active)


