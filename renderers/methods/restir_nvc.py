"""`restir-nvc`: `restir-di` whose initial candidates come from a neural visibility cache.

The Neural Visibility Cache paper, Sec. 4.1.1: ReSTIR's initial candidates are
drawn by the (clustered) NVC instead of by power, and the reservoir they make
enters temporal and spatial reuse as before. Per pixel the cache is queried
once; each of the ``candidates`` light samples then picks a cluster c with the
exact pmf P(c | x) ∝ U_c(x) * max(V_c(x), clamp) and a light uniformly in it
(Sec. 3.4's source pdf P(c | x) / m_c), or, with at most 32 lights and
``clusters`` 0, a light with the per-light NVC pmf; then a point uniform on
the light's area. That exact source pdf is the p(y_i) of the RIS weights
p̂(y_i) / (C p(y_i)) (renderers.integrators.restir), so the estimator stays
unbiased for any state of the cache. Every frame first trains the cache as
`nvc-lights` does (one Adam step on shadow rays from ``world_points`` +
``camera_points`` positions); the paper's initial candidates need no shadow ray
of their own, but the unbiased reservoir keeps its one shadow ray for the
chosen sample.

==================  ========  =====================================================
parameter           default   meaning
==================  ========  =====================================================
(restir-di's)                 candidates, temporal, m_clamp, spatial,
                              spatial_neighbours, spatial_radius, max_depth (2)
clamp, world_points, camera_points, pretrain_frames, clusters, cache
                              the visibility cache, as `nvc-lights`
==================  ========  =====================================================

Applies to scenes whose emitters are all area emitters (at least 2) and a surface.
"""

from __future__ import annotations

from typing import Any

from renderers.methods import register
from renderers.methods.base import (
    FrameHooks,
    Knob,
    Method,
    RenderOutput,
    fixed_stages,
    run_frames,
)
from renderers.methods.cached import cache_method_stats, point_training
from renderers.methods.nvc_lights import (
    VisibilityCacheParams,
    clusters_kept,
    light_selection,
    pretrain,
    train_frame,
    training_points,
)
from renderers.methods.pt import SPP_CANDIDATES
from renderers.methods.restir_di import ReSTIRDIParams, ReSTIRFrame, shadow_rays
from renderers.methods.restir_di import applies as restir_applies
from renderers.seeding import derive_seed
from renderers.timing import StageTimer


class ReSTIRNVCParams(ReSTIRDIParams, VisibilityCacheParams):
    """restir-di's reservoirs plus the visibility cache's parameters (module docstring)."""


def render(scene: Any, params: ReSTIRNVCParams, *, seed_parts: tuple[Any, ...], spp: int,
           frames: int, hooks: FrameHooks = FrameHooks()) -> RenderOutput:
    """Pre-train the cache, then train it and run the reservoirs every frame."""
    from renderers.integrators.restir import ReSTIRDI, check_scene

    check_scene(scene.scene)
    selector, cache = light_selection(scene, params, derive_seed(*seed_parts, "cache"))
    pretrain_s = pretrain(train_frame, scene, cache, params, seed_parts)
    restir = ReSTIRDI(scene.scene, params, replicas=spp, lights=selector(scene.scene))

    def train(index: int, seed: int, timer: StageTimer) -> None:
        train_frame(scene, cache, params, derive_seed(seed, "train"), timer)

    output = run_frames(ReSTIRFrame(restir, train, cache), seed_parts=seed_parts, frames=frames,
                        spp=spp, hooks=hooks)
    output.method_stats = {"shadow_rays_per_sample": shadow_rays(params),
                           **cache_method_stats(
                               cache, params, pretrain_s, [],
                               point_training(cache.config, training_points(params)))}
    return output


def applies(features: Any) -> tuple[bool, str]:
    """restir-di's scenes with at least 2 emitters (one emitter: nothing to select); not
    an animation moving shapes of a scene whose lights are clustered (nvc-lights')."""
    if features.emitter_count == 1:
        return False, "one emitter: nothing to select"
    return clusters_kept(features) or restir_applies(features)


METHOD = register(Method("restir-nvc",
                "restir-di with initial candidates from a (clustered) neural visibility cache "
                "(paper Sec. 4.1.1): direct light at primary hits only (max_depth 2)",
                ReSTIRNVCParams, render, version=5, requires=applies, label="ReSTIR NVC",
                knob=Knob("spp", SPP_CANDIDATES), unbiased=True,
                correlated_pixels=True, correlated_frames=True,
                stage_sizes=fixed_stages("training_paths", "training")))
