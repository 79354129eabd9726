"""Benchmark: cost of the neural visibility cache's light selection on this device.

Reports, measured in one run as ratios of medians of interleaved runs
(``benchmarks.bench_cache.timed_interleaved``: warm-up first, then the
functions alternate, outputs evaluated and the device synchronised):

(a) `many-lights` (32 lights), the camera's first hits at ``--res``² pixels:
    NVC selection (cache inference of 32 visibilities + unshadowed weights +
    the pick, ``NVCLightSampler.sample``) against the same pick with the
    visibilities from one shadow ray to every light instead of the cache (the
    paper's Sec. 4.3 comparison: more than 3x slower on its GPU);
(b) one frame of training: the shadow rays of the training data
    (``visibility_records``, 4096 + 4096 points x 32 lights) and one Adam step
    on them, as multiples of (a)'s NVC selection pass;
(c) `many-lights-300` (300 lights, 32 k-means clusters) at the same pixels:
    the clustered NVC's NEE pick (cluster weights, 8-candidate streaming RIS)
    and its source pick (cluster, then uniform: `restir-nvc`'s candidates)
    against power-proportional selection (``PowerLightSampler``: a table
    lookup, no per-point work) and against (a)'s per-light NVC selection.

The cache is trained for ``--train-frames`` frames first (its state does not
change the cost). The CPU is shared: read the ratios, not the milliseconds.
"""

from __future__ import annotations

import argparse
from typing import Any

from benchmarks.bench_cache import timed_interleaved
from renderers.backend import device_info, init_backend


def first_hits(mi: Any, scene: Any, res: int) -> tuple[Any, Any]:
    """(evaluated first hits of one camera ray per pixel, uniform numbers per pixel)."""
    import drjit as dr

    n = res * res
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(0, n)
    pixel = dr.arange(mi.UInt32, n)
    film = (mi.Point2f(mi.Float(pixel % res), mi.Float(pixel // res)) + sampler.next_2d()) / res
    ray, _ = scene.sensors()[0].sample_ray(0.0, sampler.next_1d(), film, sampler.next_2d())
    si = scene.ray_intersect(ray)
    u = mi.Point2f(sampler.next_2d())
    dr.eval(si, u)
    return si, u


def trained_selector(scene: Any, frames: int) -> tuple[Any, Any, Any]:
    """(light selector, cache, params) of nvc-lights after ``frames`` frames of training."""
    from renderers.methods.nvc_lights import NVCLightsParams, light_selection, train_frame
    from renderers.timing import StageTimer

    params = NVCLightsParams()
    selector, cache = light_selection(scene, params, seed=0)
    for frame in range(frames):
        train_frame(scene, cache, params, frame, StageTimer())
    return selector(scene.scene), cache, params


def shadow_ray_selector(mi: Any, nvc: Any) -> Any:
    """``nvc``'s selection with V_l(x) from one shadow ray per light instead of the cache."""
    import drjit as dr

    class ShadowRays(type(nvc)):
        def weights(self, si, active):
            weights = []
            for emitter, u in zip(self.emitters, self.unshadowed(si), strict=True):
                ds, _ = emitter.sample_direction(si, mi.Point2f(0.5, 0.5), active)
                occluded = self.scene.ray_test(si.spawn_ray_to(ds.p), active)
                weights.append(u * dr.select(occluded, self.clamp, 1.0))
            return weights

    return ShadowRays(nvc.scene)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--res", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--train-frames", type=int, default=4)
    args = parser.parse_args()

    mi = init_backend()
    from renderers.integrators.lights import PowerLightSampler
    from renderers.integrators.nvc_lights import visibility_records
    from renderers.scenes import load_scene

    lights_32 = load_scene("many-lights", args.res)
    lights_300 = load_scene("many-lights-300", args.res)
    nvc, cache, params = trained_selector(lights_32, args.train_frames)
    clustered, _, _ = trained_selector(lights_300, args.train_frames)
    rays = shadow_ray_selector(mi, nvc)
    power = PowerLightSampler(lights_300.scene)
    si_32, u_32 = first_hits(mi, lights_32.scene, args.res)
    si_300, u_300 = first_hits(mi, lights_300.scene, args.res)
    active_32, active_300 = si_32.is_valid(), si_300.is_valid()
    records = visibility_records(lights_32.scene, params.world_points, params.camera_points, 1)

    def training_step():
        cache.train(records)
        return cache.inference_parameters()

    t = timed_interleaved({
        "nvc": lambda: nvc.sample(si_32, u_32.x, active_32)[:2],
        "rays": lambda: rays.sample(si_32, u_32.x, active_32)[:2],
        "train_data": lambda: visibility_records(lights_32.scene, params.world_points,
                                                 params.camera_points, 2).target,
        "train_step": training_step,
        "clustered_nee": lambda: clustered.select(si_300, u_300, active_300)[:3],
        "clustered_source": lambda: clustered.sample(si_300, u_300.x, active_300)[:2],
        "power_300": lambda: power.sample(si_300, u_300.x, active_300)[:2],
    }, args.repeats)

    print(f"device: {device_info()['device_key']}  {args.res}x{args.res} first hits  "
          f"median of {args.repeats} interleaved runs (shared CPU: ratios, not ms)")
    print(f"(a) 32 lights, per pixel: NVC selection {t['nvc'] * 1e3:.1f} ms, one shadow ray "
          f"per light {t['rays'] * 1e3:.1f} ms: rays / NVC = {t['rays'] / t['nvc']:.2f}x")
    print(f"(b) training frame: data (8192 points x 32 shadow rays) {t['train_data'] * 1e3:.1f} "
          f"ms = {t['train_data'] / t['nvc']:.2f}x (a)'s NVC pass; one Adam step "
          f"{t['train_step'] * 1e3:.1f} ms = {t['train_step'] / t['nvc']:.2f}x")
    print(f"(c) 300 lights, 32 clusters: NEE pick (cluster + 8-candidate RIS) "
          f"{t['clustered_nee'] * 1e3:.1f} ms = {t['clustered_nee'] / t['power_300']:.2f}x power "
          f"selection ({t['power_300'] * 1e3:.1f} ms), {t['clustered_nee'] / t['nvc']:.2f}x (a)'s "
          f"32-light NVC; source pick (cluster + uniform) {t['clustered_source'] * 1e3:.1f} ms "
          f"= {t['clustered_source'] / t['power_300']:.2f}x power")


if __name__ == "__main__":
    main()
