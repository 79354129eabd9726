"""The frame loop of the caching methods: online training every frame, then render.

Real-time semantics: every frame first traces training paths (the same PT
core, Russian roulette and ``max_depth`` as the render paths, see
docs/training.md) and takes the cache's training steps on their records, as
many as the frame's training budget (:mod:`renderers.methods.budget`) says, then
renders the frame with the updated cache — frame f uses a cache trained on
frames 0..f. Static scenes may pre-train for ``pretrain_frames`` frames before
the first timed frame. Stages timed per frame: ``training_paths``,
``training``, ``render`` (path tracing, recording the cache queries it uses)
and ``inference`` (the deferred cache queries, renderers/integrators/deferred.py).
The warm-up frame trains too. ``method_stats`` reports the cache queries
evaluated: ``cache_queries_per_frame`` (mean over the timed frames) and
``cache_query_fraction`` (queries / (lanes x the buffer's slots per lane)), and
``cache_inline_frames``, frames too large for the buffer that evaluated their
queries in the loop (renderers.integrators.cached.MAX_QUERY_SLOTS).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, ClassVar, get_args

import numpy as np
from pydantic import (
    BaseModel,
    Field,
    SerializationInfo,
    SerializerFunctionWrapHandler,
    model_serializer,
    model_validator,
)

from renderers.methods.base import FrameHooks, RenderOutput, WithParts, render_stage, run_frames
from renderers.methods.budget import (
    MIN_RECORDS,
    RECORD_FRACTION,
    BudgetMode,
    TrainingBudget,
    frame_training_budget,
)
from renderers.methods.pt import PTParams
from renderers.seeding import derive_seed
from renderers.timing import StageTimer

CACHE_AOVS = ("depth", "cache_depth", "cache_vertices")


class CacheTrainingParams(PTParams):
    """PT core parameters plus how the cache is trained online."""

    sph_c: float = Field(0.01, gt=0.0, le=1e6, description="c of the spread heuristic")
    train_fraction: float = Field(0.03, gt=0.0, le=1.0, description="training paths / pixels")
    min_train_paths: int = Field(4096, ge=1, le=1 << 22,
                                 description="floor of training paths per frame")
    record_depth: int = Field(3, ge=1, le=16, description="vertices recorded per training path")
    training_budget: BudgetMode = Field(
        "scaled", description="records per frame: 'scaled' with the pixel count, or the "
                              "papers' fixed steps_per_frame x batch_size ('paper')")
    train_record_fraction: float = Field(RECORD_FRACTION, gt=0.0, le=16.0,
                                         description="training records / pixels ('scaled')")
    min_train_records: int = Field(MIN_RECORDS, ge=1, le=1 << 24,
                                   description="floor of training records per frame ('scaled')")
    pretrain_frames: int = Field(0, ge=0, le=100_000,
                                 description="training frames before the first (warm-up) frame")
    cache: dict[str, Any] = Field(default_factory=dict, description="cache config overrides")

    @model_validator(mode="before")
    @classmethod
    def _removed_train_max_depth(cls, values: Any) -> Any:
        # Training paths used to have their own depth (default unbounded while
        # renders stopped at 8): the cache then learned another quantity than
        # the one the render and its reference estimate. They now follow
        # max_depth (docs/training.md). Stored runs keep the old field in
        # their params JSON, which is only read, never validated again.
        if isinstance(values, dict) and "train_max_depth" in values:
            raise ValueError("train_max_depth was removed: training paths now stop at "
                             "max_depth like render paths (set max_depth instead)")
        return values

    @model_validator(mode="after")
    def _scaled_only_fields(self) -> CacheTrainingParams:
        # Defaults pass, so that a dumped 'paper' parameter set validates again.
        changed = [name for name in ("train_record_fraction", "min_train_records")
                   if getattr(self, name) != type(self).model_fields[name].default]
        if self.training_budget == "paper" and changed:
            raise ValueError(f"{', '.join(changed)} only apply to training_budget='scaled'; "
                             "'paper' trains cache.steps_per_frame x cache.batch_size "
                             "records per frame")
        return self

    def core(self) -> dict[str, Any]:
        """The PT core's plugin properties."""
        return {"max_depth": self.max_depth, "rr_depth": self.rr_depth,
                "rr_mode": self.rr_mode, "rr_survival": self.rr_survival}


#: A caching method's adaptive equal-bias points (jobs/sweeps/sweep.py): adaptive
#: termination reads the sweep's v1 mask; the sweep's snapshots are the training.
ADAPTIVE_EQUAL_BIAS: dict[str, Any] = {"termination": "adaptive", "pretrain_frames": 0}


class TerminationChoice(BaseModel):
    """A caching method's termination policy (renderers.integrators.termination):
    ``termination`` names it (the method declares the field with the names of the
    policies that serve its cache) and ``termination_params`` holds the policy's own
    parameters as one typed object (the method declares it with the union of those
    policies' tagged models, ``termination_params_type``), validated once, where the
    method's parameters are parsed. Stored and sent, ``termination_params`` holds the
    parameters that were given, without the tag, and is left out when none was, so
    parameter sets from before policies had parameters dump, store and hash as they did.
    Fields named in ``DUMPED_OFF_DEFAULT`` (parameters added later whose default renders
    as before) are likewise left out at their default."""

    DUMPED_OFF_DEFAULT: ClassVar[tuple[str, ...]] = ()

    @model_validator(mode="before")
    @classmethod
    def _tag_termination_params(cls, values: Any) -> Any:
        # The stored form names the policy once, in termination; its parameters' model
        # is told by the tag ``policy``, filled in from that name.
        if not isinstance(values, dict):
            return values
        named = cls.model_fields["termination"]
        name = values.get("termination", named.default)
        own = values.get("termination_params", {})
        if not isinstance(own, dict) or name not in get_args(named.annotation):
            return values    # refused by the fields' own validation
        if "policy" in own:
            raise ValueError("termination_params.policy: the policy is named by termination")
        return {**values, "termination_params": {**own, "policy": name}}

    @model_validator(mode="after")
    def _parameters_of_the_named_policy(self) -> TerminationChoice:
        if self.termination_params.policy != self.termination:  # type: ignore[attr-defined]
            raise ValueError(f"termination_params are {self.termination_params.policy}'s, "  # type: ignore[attr-defined]
                             f"the policy is {self.termination}")  # type: ignore[attr-defined]
        return self

    @model_serializer(mode="wrap")
    def _untagged_termination_params(self, handler: SerializerFunctionWrapHandler,
                                     info: SerializationInfo) -> dict[str, Any]:
        data = handler(self)
        del data["termination_params"]
        for name in self.DUMPED_OFF_DEFAULT:
            if getattr(self, name) == type(self).model_fields[name].default:
                data.pop(name, None)
        given = self.termination_params.model_dump(  # type: ignore[attr-defined]
            mode=info.mode, exclude_unset=True, exclude={"policy"})
        return {"termination_params": given, **data} if given else data

    def termination_settings(self) -> Any:
        """What the policy takes from the method besides its own parameters (sph_c; N_c
        where the method has it, :meth:`termination_nc`)."""
        from renderers.integrators.termination import TerminationSettings

        return TerminationSettings(self.sph_c, self.termination_nc())  # type: ignore[attr-defined]

    def termination_nc(self) -> tuple[int, int]:
        """N_c at the first vertex and later, for the policy (none by default)."""
        return (0, 0)

    def termination_policy(self) -> Any:
        """The configured policy object the integrator asks at each vertex."""
        from renderers.integrators.termination import make_policy

        return make_policy(self.termination_params,  # type: ignore[attr-defined]
                           self.termination_settings())


def termination_params_field() -> Any:
    """The field ``termination_params`` (typed with ``termination_params_type`` of the
    method's kind of cache), filled in from ``termination`` where it is not given; its
    default, None, stands in only where ``termination`` is refused."""
    return Field(None, description="the termination policy's own parameters")


def load_integrators(plugin: str, params: CacheTrainingParams, key_vertex: str,
                     trainer_plugin: str | None = None) -> tuple[Any, Any]:
    """The render integrator (plugin ``plugin``) and its training-path integrator
    (``trainer_plugin``, by default plain PT training paths), both configured with
    the method's validated ``params``. The plugins must be registered
    (renderers.integrators.register_plugins)."""
    import mitsuba as mi

    from renderers.integrators import training

    trainer_plugin = trainer_plugin or training.TrainingPathIntegrator.plugin_name
    integrator = mi.load_dict({"type": plugin, **params.core()})
    integrator.configure(params)
    # Training paths are bounded exactly like render paths (same core, same
    # max_depth counted from the camera): a record at vertex x_j then sees the
    # depth budget a render path terminating into the cache at x_j had left.
    trainer = mi.load_dict({"type": trainer_plugin, **params.core(),
                            "record_depth": params.record_depth, "key_vertex": key_vertex})
    trainer.configure(params)
    return integrator, trainer


def make_cache(scene: Any, config: Any, seed: int) -> Any:
    """A cache over the scene's bounding box with ``config``, a validated CacheConfig
    (the parameters' :meth:`~renderers.methods.base.MethodParams.cache_config`)."""
    from renderers.caches import NeuralCache

    bbox = scene.scene.bbox()
    return NeuralCache(config, list(bbox.min), list(bbox.max), seed=seed)


def train_once(cache: Any, trainer: Any, scene: Any, budget: TrainingBudget, seed: int,
               timer: StageTimer) -> None:
    """One frame of online training: trace the budget's training paths, take its steps."""
    from renderers.caches import TrainingRecords

    with timer.stage("training_paths"):
        records = trainer.trace_records(scene.scene, budget.paths, seed)
    with timer.stage("training"):
        cache.train(TrainingRecords(**records), steps=budget.steps, batch_size=budget.batch_size)


#: A second cache's frame of training (seed, timer), taken after the first's.
ExtraTraining = Callable[[int, StageTimer], None]


def render_with_cache(
    scene: Any, params: CacheTrainingParams, integrator: Any, trainer: Any, cache: Any, *,
    seed_parts: tuple[Any, ...], spp: int, frames: int, hooks: FrameHooks = FrameHooks(),
    extra_training: ExtraTraining | None = None, extra_cache: Any = None,
) -> RenderOutput:
    """Pre-train, then run the frame loop with training before every frame.
    ``extra_training``: a second cache's (``extra_cache``) training, in every frame that
    trains."""
    # Self-training paths query the cache too.
    integrator.cache = trainer.cache = cache
    width, height = scene.resolution
    budget = frame_training_budget(width * height, params, cache.config)

    def train(seed: int, timer: StageTimer) -> None:
        train_once(cache, trainer, scene, budget, seed, timer)
        if extra_training is not None:
            extra_training(derive_seed(seed, "second cache"), timer)

    pretrain_start = time.perf_counter()
    for index in range(params.pretrain_frames):
        train(derive_seed(*seed_parts, "pretrain", index), StageTimer())
    pretrain_s = time.perf_counter() - pretrain_start

    render = render_stage(scene, integrator, spp)

    frame_queries: list[list[Any]] = []  # the QueryCounts of each timed frame

    def render_frame(index: int, seed: int, timer: StageTimer):
        train(derive_seed(seed, "train"), timer)
        integrator.query_counts.clear()
        image = render(index, seed, timer)
        if index >= 0:  # not the warm-up frame
            frame_queries.append(list(integrator.query_counts))
        return image

    # What settles in the warm-up besides the render: the training steps, the training
    # paths and a second cache's training records.
    extra = (() if extra_cache is None
             else (extra_cache, getattr(extra_cache, "training_records", None)))
    counted = tuple(c for c in (cache, *extra, trainer) if c is not None)
    output = run_frames(WithParts(render_frame, render, counted=counted),
                        seed_parts=seed_parts, frames=frames,
                        spp=spp,
                        aov_names=CACHE_AOVS, hooks=hooks)
    output.method_stats = cache_method_stats(cache, params, pretrain_s, frame_queries,
                                             budget.describe())
    return output


def cache_record(cache: Any, per_frame: dict[str, Any]) -> dict[str, Any]:
    """A cache's resolved configuration as a run stores it (``method_stats['caches']``):
    the whole network config after preset and overrides (encodings, MLP, output, loss,
    optimizer, EMA, batch and steps) and what it trains on per frame (``per_frame``:
    paths or points, steps, batch size, records) and its trainable floats (``parameters``:
    the hash grid's and the MLP's)."""
    return {"config": cache.config.model_dump(mode="json"), "per_frame": per_frame,
            "parameters": cache.describe()["total_params"]}


def cache_method_stats(cache: Any, params: Any, pretrain_s: float,
                       frame_queries: list[list[Any]],
                       per_frame: dict[str, Any]) -> dict[str, Any]:
    """What a run stores of its cache: queries per frame, pre-training, losses, and its
    resolved configuration under the name of the parameter that overrides it
    (``caches['cache']``, :func:`cache_record`)."""
    return {
        **(query_stats(frame_queries) if frame_queries else {}),
        "pretrain_frames": params.pretrain_frames,
        "pretrain_s": pretrain_s,
        "loss_history": list(cache.loss_history),
        "cache_stats": {**cache.stats, "nonfinite_weights": nonfinite_weights(cache),
                        "min_trained_steps": cache.config.min_trained_steps},
        "caches": {"cache": cache_record(cache, per_frame)},
    }


def point_training(config: Any, points: int) -> dict[str, int]:
    """The per-frame training of a cache trained on ``points`` points a frame (the
    visibility caches, `nrc-di`): ``config.steps_per_frame`` steps of its batch."""
    return {"points": points, "steps": config.steps_per_frame,
            "batch_size": config.batch_size,
            "records": config.steps_per_frame * config.batch_size}


def nonfinite_weights(cache: Any) -> int:
    """NaN or infinite entries of the weights the cache infers with (what a snapshot
    stores); a skipped training step (renderers.caches.cache) keeps this 0."""
    return sum(int(np.count_nonzero(~np.isfinite(values)))
               for values in cache.inference_parameters().values())


def query_stats(frames: list[list[Any]]) -> dict[str, float]:
    """Over the frames that deferred their cache queries: the mean queries evaluated
    per frame and the mean fraction of the buffer's slots they filled (``QueryCount``s
    of renderers.integrators.deferred); and how many frames evaluated them in the
    loop instead (a count of None: the buffer would have been too large)."""
    deferred = [counts for counts in frames if None not in counts]
    stats: dict[str, float] = {"cache_inline_frames": len(frames) - len(deferred)}
    if deferred:
        queries = [sum(c.queries for c in counts) for counts in deferred]
        slots = [sum(c.lanes * c.slots_per_lane for c in counts) for counts in deferred]
        stats["cache_queries_per_frame"] = sum(queries) / len(deferred)
        stats["cache_query_fraction"] = sum(
            q / max(s, 1) for q, s in zip(queries, slots, strict=True)) / len(deferred)
    return stats


def cached_render(build: Callable[[Any, Any, int], tuple[Any, Any, Any]]) -> Callable[..., RenderOutput]:
    """The render function of a caching method whose integrators and cache ``build`` makes.

    ``build(scene, params, seed)`` returns (render integrator, training integrator, cache).
    """

    def render(scene: Any, params: CacheTrainingParams, *, seed_parts: tuple[Any, ...],
               spp: int, frames: int, hooks: FrameHooks = FrameHooks()) -> RenderOutput:
        integrator, trainer, cache = build(scene, params, derive_seed(*seed_parts, "cache"))
        output = render_with_cache(scene, params, integrator, trainer, cache,
                                   seed_parts=seed_parts, spp=spp, frames=frames, hooks=hooks)
        if getattr(params, "estimator", None) == "unbiased":
            probe_residuals(scene, params, cache, output, spp=max(spp, 2),
                            seed=derive_seed(*seed_parts, "residual probe"))
        return output

    return render


def probe_residuals(scene: Any, params: Any, cache: Any, output: RenderOutput, *, spp: int,
                    seed: int) -> None:
    """After the frame loop, untimed: ``spp`` residual samples per pixel of the two-level
    estimator with the final ``cache`` (renderers.integrators.residual_probe), kept as
    ``output.residual_variance`` (metrics.residual_variance) and described in
    ``method_stats['residual_probe']``."""
    import mitsuba as mi

    from renderers.integrators.residual_probe import ResidualProbe

    probe = mi.load_dict({"type": ResidualProbe.plugin_name, **params.core()})
    probe.configure(params)
    probe.cache = cache
    keep_residual_variance(output, *probe.residual_samples(scene.scene, spp, seed), spp=spp)


def keep_residual_variance(output: RenderOutput, values: np.ndarray, probed: np.ndarray, *,
                           spp: int) -> None:
    """Keep the per-pixel variance of a probe's residual samples (``values`` (H, W, spp, 3),
    ``probed`` (H, W, spp); metrics.residual_variance) as ``output.residual_variance``,
    described in ``method_stats['residual_probe']``."""
    from metrics.residual_variance import residual_variance_map

    output.residual_variance, nonfinite = residual_variance_map(values, probed)
    output.method_stats["residual_probe"] = {
        "samples_per_pixel": spp,
        "pixels": int(np.isfinite(output.residual_variance).all(axis=-1).sum()),
        "nonfinite_samples": nonfinite,
    }


def training_stage_sizes(params: Any, pixels: int, _spp: int) -> dict[str, float]:
    """Training paths and records of a frame of ``pixels`` pixels: the training budget's
    rule, floors and cap included (:func:`frame_training_budget`)."""
    budget = frame_training_budget(pixels, params, params.cache_config())
    return {"training_paths": budget.paths, "training": budget.records}


def scale_training_floors(params: Any, factor: float) -> Any:
    """``params`` with the floors of training records and paths per frame scaled by
    ``factor`` ('paper' budgets have no floor: unchanged)."""
    if params.training_budget == "paper":
        return params
    fields = type(params).model_fields
    scaled = {name: min(round(getattr(params, name) * factor), _upper_bound(fields[name]))
              for name in ("min_train_records", "min_train_paths")}
    return type(params).model_validate({**params.model_dump(), **scaled})


def _upper_bound(field: Any) -> int:
    return next(m.le for m in field.metadata if getattr(m, "le", None) is not None)



def has_surface(features: Any) -> tuple[bool, str]:
    """A cache is keyed on surface points: a caching method needs a scene with shapes."""
    if features.shape_count == 0:
        return False, "the scene has no surface for the cache to live on"
    return True, ""
