"""A neural cache of the direct light at primary hits (`nrc-di`), the NVC paper's baseline.

Neural Visibility Cache paper, Sec. 4.2 ("NRC DI"): the network of the
visibility cache (hash grid + 2 x 32 leaky-ReLU MLP, renderers.caches.
direct_light_config) with three unbounded outputs, the RGB direct light
reflected at a position, trained online on one-sample estimates of it; the
image is the prediction at the camera rays' first hits (biased, noise-free):

    D(x, ω_o) ≈ cache(x)

Training records (:func:`direct_light_records`), per frame, like the
visibility cache's (renderers.integrators.nvc_lights.visibility_records):
``camera_points`` first hits of camera rays through uniformly random film
positions (screen space, ω_o toward the camera), and ``world_points`` first
hits of rays from uniform points of the scene's bounding box in uniform
directions (ω_o back along the ray). The NVC's world-space points are points
in space; reflected light needs a surface, so here they are the surface
points those rays reach, seen and unseen by the camera. Each target is one
NEE sample of the direct light at the point (Mitsuba's emitter sampling, one
shadow ray):

    target = f(x, ω_o, ω_l) L_e(y) G V / (p(l) p(y | l))

whose expectation is D(x, ω_o). The network has no direction input (as the
NVC's), so it learns the mean over the ω_o its records had: exact for diffuse
surfaces.
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi

from renderers.caches import TrainingRecords
from renderers.frozen import FrozenRecords
from renderers.integrators import register
from renderers.integrators.primary import PrimaryHitIntegrator

PLUGIN_NAME = "nirc_nrc_di"


@register
class NRCDIIntegrator(PrimaryHitIntegrator):
    """D(x) = the cache's RGB prediction at the first hit (module docstring);
    ``cache`` must be set on the loaded instance (:meth:`with_cache`)."""
    plugin_name = PLUGIN_NAME

    cache: Any = None

    def with_cache(self, cache: Any) -> NRCDIIntegrator:
        if cache.n_outputs != 3:
            raise ValueError(f"nrc-di needs an RGB cache (3 outputs), got {cache.n_outputs}")
        self.cache = cache
        return self

    def frame_state(self, scene: mi.Scene) -> dict[str, Any]:
        return {"cache": self.cache.inference_state()}

    def bind_frame_state(self, scene: mi.Scene, state: dict[str, Any]) -> None:
        self.cache.bind_inference(state["cache"])

    def direct(self, scene, sampler, si, active):
        if self.cache is None:
            raise ValueError("NRCDIIntegrator needs a cache: call with_cache(cache) first")
        rgb = self.cache.query(self.cache.surface_features(si.p))
        return dr.select(active, rgb, 0.0)


def direct_light_records(scene: mi.Scene, world_points: int, camera_points: int,
                         seed: int) -> TrainingRecords:
    """One frame of training data: surface points and one NEE sample of their direct
    light each (module docstring)."""
    return DirectLightRecords(world_points, camera_points, frozen=False)(scene, seed)


class DirectLightRecords(FrozenRecords):
    """:func:`direct_light_records` of a cache's settings, frozen (renderers.frozen) where
    freezing is on: the seed is the recording's argument."""

    def __init__(self, world_points: int, camera_points: int,
                 frozen: bool | None = None) -> None:
        self.world_points, self.camera_points = world_points, camera_points
        super().__init__(frozen)

    def arguments(self, seed: int) -> tuple[Any, ...]:
        return (dr.opaque(mi.UInt32, seed),)

    def records(self, scene: mi.Scene, seed: mi.UInt32) -> TrainingRecords:
        world_points = self.world_points
        n = world_points + self.camera_points
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed, n)

        # World-space rays: uniform origins in the bounding box, uniform directions.
        box = scene.bbox()
        u = mi.Vector3f(sampler.next_1d(), *sampler.next_2d())
        world_ray = mi.Ray3f(box.min + u * (box.max - box.min),
                             mi.warp.square_to_uniform_sphere(sampler.next_2d()))
        # Screen-space rays: through uniformly random film positions.
        camera_ray, _ = scene.sensors()[0].sample_ray(time=0.0, sample1=sampler.next_1d(),
                                                      sample2=sampler.next_2d(),
                                                      sample3=sampler.next_2d())
        world = dr.arange(mi.UInt32, n) < world_points
        si = scene.ray_intersect(mi.Ray3f(dr.select(world, world_ray.o, camera_ray.o),
                                          dr.select(world, world_ray.d, camera_ray.d)))
        valid = si.is_valid()

        ds, emitted = scene.sample_emitter_direction(si, sampler.next_2d(valid), True, valid)
        f = si.bsdf().eval(mi.BSDFContext(), si, si.to_local(ds.d), valid & (ds.pdf > 0))
        target = dr.select(valid & (ds.pdf > 0), mi.Color3f(f * emitted), 0.0)
        records = TrainingRecords(position=si.p, target=target, valid=valid)
        dr.eval(records.position, records.target, records.valid)
        return records


