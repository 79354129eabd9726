"""`nvc-lights`: the PT core with lights selected by a neural visibility cache.

At every shading vertex (NEE of full global illumination, not only at the
primary hit) light l is picked with p(l | x) ∝ U_l(x) * max(V_l(x), clamp):
U_l the unshadowed contribution (power / squared distance times a cosine
bound), V_l the visibility the cache predicts (Neural Visibility Cache paper,
Sec. 3.1). The selector, :class:`renderers.integrators.nvc_lights.NVCLightSampler`,
drives NEE and the MIS weight of BSDF-sampled emitter hits alike, so each
frame is unbiased for any cache (docs/estimators.md, "nvc-lights").

Every frame first trains the cache (one Adam step on ``world_points`` +
``camera_points`` positions with one shadow ray per light each, stage
``training_paths`` for the shadow rays, ``training`` for the step), then
renders with it; ``pretrain_frames`` frames of training may come first.

==================  ========  =====================================================
parameter           default   meaning
==================  ========  =====================================================
max_depth, rr_*     as `pt`   the PT core (renders and nothing else: training
                              traces shadow rays only)
clamp               0.001     floor of the predicted visibility (paper Sec. 3.1,
                              Fig. 5), at least 1e-6: the sigmoid is exactly 0 in
                              float32 below about -88, so without a floor a light
                              the cache wrongly calls occluded gets pmf 0 (the
                              paper's biased case)
world_points        4096      training positions per frame uniform in the scene's
                              bounding box (paper Sec. 3.3)
camera_points       4096      training positions per frame at first hits of random
                              camera rays (paper Sec. 3.3)
pretrain_frames     0         training frames before the first (warm-up) frame
clusters            0         0: one output per light up to 32 lights, 32 clusters
                              beyond; k > 0: k-means of the lights into at most k
                              clusters, one output each (paper Sec. 3.4)
cluster_candidates  8         streaming RIS candidates within the picked cluster
cache               {}        overrides of the cache preset
                              (``renderers.caches.visibility_config``: hash grid
                              10 levels x 4 features, base resolution 16; MLP
                              2 x 32 leaky ReLU 0.01; sigmoid outputs; L2; Adam
                              lr 0.05 -> 0.001 over 200 steps; batch 8192, 1 step
                              per frame)
==================  ========  =====================================================

Clustered (``clusters`` > 0, or more than 32 emitters): cluster c is picked with
the exact pmf ∝ U_c(x) * max(V_c(x), clamp), then one of its lights by
streaming RIS with an unbiased contribution weight; NEE weights by it and the
MIS weights use the exact source pmf P(c | x) / m_c (unbiased; docs/estimators.md,
"Clustered NVC"). Applies to scenes with at least 2 emitters (environment and
delta emitters included) and a surface.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from pydantic import Field

from renderers.methods import register
from renderers.methods.base import (
    FrameHooks,
    Knob,
    Method,
    MethodParams,
    RenderOutput,
    WithParts,
    fixed_stages,
    render_stage,
    run_frames,
)
from renderers.methods.cached import (
    cache_method_stats,
    has_surface,
    make_cache,
    point_training,
)
from renderers.methods.pt import SPP_CANDIDATES, PTParams, path_integrator
from renderers.seeding import derive_seed
from renderers.timing import StageTimer

#: One output per light up to this many; beyond, clusters (paper Sec. 3.4).
MAX_LIGHTS = 32
#: The smallest clamp accepted. The clamp is what keeps these methods unbiased (a
#: light's weight U * max(V, clamp) never 0 where it can contribute); it must stay a
#: float32 weight well above underflow for small unshadowed terms U, which a clamp of
#: 1e-6 does for U down to ~1e-32.
MIN_CLAMP = 1e-6


def one_output_visibility_config(**overrides: Any) -> Any:
    """The visibility preset with one output: what parsing checks overrides against (the
    output count comes from the scene; any count checks them alike)."""
    from renderers.caches.config import visibility_config

    return visibility_config(1, **overrides)


class VisibilityCacheParams(MethodParams):
    """The visibility cache's parameters (module docstring), shared by `restir-nvc`."""

    clamp: float = Field(1e-3, ge=MIN_CLAMP, le=1.0,
                         description="floor of the predicted visibility; what keeps the "
                                     "method unbiased, so at least 1e-6")
    world_points: int = Field(4096, ge=0, le=1 << 20,
                              description="training points per frame in the scene's box")
    camera_points: int = Field(4096, ge=0, le=1 << 20,
                               description="training points per frame at camera first hits")
    pretrain_frames: int = Field(0, ge=0, le=100_000,
                                 description="training frames before the first (warm-up) frame")
    clusters: int = Field(0, ge=0, le=MAX_LIGHTS,
                          description="0: per light up to 32 lights, else at most this many "
                                      "k-means clusters")
    cache: dict[str, Any] = Field(default_factory=dict, description="cache config overrides")

    def cache_presets(self) -> dict[str, Any]:
        return {"cache": one_output_visibility_config}

    def cluster_count(self, emitters: int) -> int:
        """0 (one output per light) or the clusters to ask k-means for."""
        if self.clusters:
            return self.clusters
        return MAX_LIGHTS if emitters > MAX_LIGHTS else 0


class NVCLightsParams(PTParams, VisibilityCacheParams):
    """The PT core's parameters plus the visibility cache's (module docstring)."""

    cluster_candidates: int = Field(8, ge=1, le=64,
                                    description="RIS candidates within the picked cluster")

    def core(self) -> PTParams:
        """The PT core's parameters."""
        return PTParams(**self.model_dump(include=set(PTParams.model_fields)))


def light_selection(scene: Any, params: VisibilityCacheParams, seed: int,
                    cluster_candidates: int = 8) -> tuple[type, Any]:
    """(light selector type bound to a new untrained cache, the cache), per light or
    clustered by ``params``. The cache carries its clusters (``cache.clusters``, None per
    light) and its frame's training records (``cache.training_records``) for
    :func:`train_frame`."""
    from renderers.integrators.nvc_lights import (
        ClusteredNVCLightSampler,
        NVCLightSampler,
        cluster_lights,
    )

    count = len(scene.scene.emitters())
    wanted = params.cluster_count(count)
    clusters = cluster_lights(scene.scene, wanted) if wanted else None
    outputs = count if clusters is None else clusters.count
    cache = visibility_cache(scene, params, seed, outputs, clusters)
    if clusters is None:
        return NVCLightSampler.bound_to(cache, params.clamp), cache
    return ClusteredNVCLightSampler.bound_to_clusters(
        cache, clusters, params.clamp, cluster_candidates), cache


def with_outputs(params: VisibilityCacheParams, outputs: int) -> Any:
    """The parsed cache config (:func:`one_output_visibility_config` with the overrides)
    with ``outputs`` outputs, unless the overrides set the count themselves."""
    config = params.cache_config()
    if "n_outputs" in (params.cache.get("output") or {}):
        return config
    return config.model_copy(
        update={"output": config.output.model_copy(update={"n_outputs": outputs})})


def visibility_cache(scene: Any, params: VisibilityCacheParams, seed: int, outputs: int,
                     clusters: Any = None) -> Any:
    """A new visibility cache of ``outputs`` (one per light, or per cluster of ``clusters``)
    carrying what :func:`train_frame` reads: its clusters (``cache.clusters``) and its
    frame's training records (``cache.training_records``)."""
    from renderers.integrators.nvc_lights import VisibilityRecords

    cache = make_cache(scene, with_outputs(params, outputs), seed)
    cache.clusters = clusters
    cache.training_records = VisibilityRecords(params.world_points, params.camera_points,
                                               clusters)
    return cache


def build(scene: Any, params: NVCLightsParams, seed: int) -> tuple[Any, Any]:
    """(integrator, visibility cache): the PT core selecting lights with an untrained cache."""
    integrator = path_integrator(params.core())
    integrator.light_sampler_type, cache = light_selection(scene, params, seed,
                                                           params.cluster_candidates)
    return integrator, cache


def train_frame(scene: Any, cache: Any, params: VisibilityCacheParams, seed: int,
                timer: StageTimer) -> None:
    """One frame of online training: the cache's ``training_records`` of the frame
    (shadow rays to every light or one light per cluster, :func:`light_selection`; the
    environment's for `nvc-env`, NEE samples for `nrc-di`), then the cache's step."""
    with timer.stage("training_paths"):
        records = cache.training_records(scene.scene, seed)
    with timer.stage("training"):
        cache.train(records)


def training_points(params: Any) -> int:
    """Training points per frame: world-space and camera points (`nvc-env` trains on
    camera points only)."""
    return getattr(params, "world_points", 0) + params.camera_points


def pretrain(train_frame: Callable[[Any, Any, Any, int, StageTimer], None], scene: Any,
             cache: Any, params: Any, seed_parts: tuple[Any, ...]) -> float:
    """The one-off training frames before the first frame (``params.pretrain_frames``);
    their seconds (not per-frame time)."""
    start = time.perf_counter()
    for index in range(params.pretrain_frames):
        train_frame(scene, cache, params, derive_seed(*seed_parts, "pretrain", index),
                    StageTimer())
    return time.perf_counter() - start


def visibility_cache_render(build: Callable[[Any, Any, int], tuple[Any, Any]],
                            train_frame: Callable[[Any, Any, Any, int, StageTimer], None],
                            ) -> Callable[..., RenderOutput]:
    """The frame loop of a visibility-cache method (`nvc-lights`, `nvc-env`) from its
    ``build(scene, params, seed) -> (integrator, cache)`` and its ``train_frame``."""

    def render(scene: Any, params: Any, *, seed_parts: tuple[Any, ...], spp: int,
               frames: int, hooks: FrameHooks = FrameHooks()) -> RenderOutput:
        """Pre-train, then train and render every frame (the caching methods' frame loop)."""
        integrator, cache = build(scene, params, derive_seed(*seed_parts, "cache"))

        pretrain_s = pretrain(train_frame, scene, cache, params, seed_parts)

        render_only = render_stage(scene, integrator, spp)
        # A deferred-query integrator (renderers.integrators.cached) counts its queries.
        counts = getattr(integrator, "query_counts", None)
        frame_queries: list[list[Any]] = []

        def render_frame(index: int, seed: int, timer: StageTimer):
            train_frame(scene, cache, params, derive_seed(seed, "train"), timer)
            if counts is not None:
                counts.clear()
            image = render_only(index, seed, timer)
            if counts is not None and index >= 0:  # not the warm-up frame
                frame_queries.append(list(counts))
            return image

        counted = (cache, getattr(cache, "training_records", None))
        output = run_frames(WithParts(render_frame, render_only,
                                      counted=tuple(c for c in counted if c is not None)),
                            seed_parts=seed_parts,
                            frames=frames, spp=spp,
                            aov_names=tuple(integrator.aov_names()), hooks=hooks)
        output.method_stats = cache_method_stats(
            cache, params, pretrain_s, frame_queries,
            point_training(cache.config, training_points(params)))
        return output

    return render


render = visibility_cache_render(build, train_frame)


def applies(features: Any) -> tuple[bool, str]:
    """At least 2 emitters (beyond 32 clustered) and a surface for the cache to live on;
    not an animation moving shapes of a scene whose lights are clustered."""
    if features.emitter_count < 2:
        count = "one emitter" if features.emitter_count == 1 else "no emitter"
        return False, f"{count}: nothing to select"
    return clusters_kept(features) or has_surface(features)


def clusters_kept(features: Any) -> tuple[bool, str] | None:
    """(False, why) where the light clusters of more than MAX_LIGHTS emitters, grouped by
    position once at load time (:func:`light_selection`), would go stale: an animation
    that moves shapes (their emitters with them); None otherwise."""
    if "shapes" in features.animation_changes and features.emitter_count > MAX_LIGHTS:
        return False, (f"the animation moves shapes and the scene's {features.emitter_count} "
                       f"emitters (more than {MAX_LIGHTS}) are clustered by position once at "
                       "load time; a scene update does not cluster them again")
    return None


METHOD = register(Method("nvc-lights",
                "path tracing with lights selected by a neural visibility cache "
                "(power / distance^2 x cosine bound x max(V, clamp)) at every vertex",
                NVCLightsParams, render, version=2,
                requires=applies, label="NVC lights", knob=Knob("spp", SPP_CANDIDATES),
                unbiased=True, stage_sizes=fixed_stages("training_paths", "training")))
