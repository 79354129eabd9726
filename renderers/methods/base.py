"""What every render method has in common: parameters, the frame loop, its output.

A method is a pure function of (scene, method parameters, seed, spp, frames)
-> images + statistics (docs/design.md, "Layout"). The frame loop gives all methods
the same real-time semantics and the same timing protocol: one warm-up frame
(excluded, reported), then F timed frames, each rendered with its own derived
seed and accumulated into the running mean, wall and kernel frames interleaved
(renderers.timing).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, PrivateAttr, ValidationError, model_validator

from renderers.backend import host_runs_kernels
from renderers.frozen import MAX_WARMUP_FRAMES, SETTLED_CALLS, Frozen, freezing
from renderers.load import LoadMonitor
from renderers.seeding import derive_seed
from renderers.timing import (
    KERNEL,
    KERNEL_EVERY,
    FrameTime,
    StageTimer,
    Warmup,
    frame_kind,
    history_states,
    kernel_history,
    summarize,
    synchronize,
)


class MethodParams(BaseModel):
    """Base of every method's parameter model: unknown fields are errors, and so are
    cache overrides its cache preset cannot build (:meth:`cache_presets`). The configs
    built from them while parsing are kept (:meth:`cache_config`): what the caches are
    made with, not validated again."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    _cache_configs: dict[str, Any] = PrivateAttr(default_factory=dict)

    def cache_presets(self) -> dict[str, Callable[..., Any]]:
        """Each field of cache-config overrides and the preset (a function of
        renderers.caches.config) it overrides; checked when the parameters are
        parsed, so a bad override is refused at submission, not when a job runs."""
        return {}

    @model_validator(mode="after")
    def _cache_overrides_build(self) -> MethodParams:
        for name, preset in self.cache_presets().items():
            try:
                self._cache_configs[name] = preset(**getattr(self, name))
            except ValidationError as error:
                detail = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}"
                                   for e in error.errors())
                raise ValueError(f"{name}: {detail}") from None
            except (ValueError, TypeError, AttributeError) as error:
                raise ValueError(f"{name}: {error}") from None
        return self

    def cache_config(self, name: str = "cache") -> Any:
        """The typed config of the cache whose overrides are the field ``name``: its
        preset with the overrides, built and validated when the parameters were parsed."""
        return self._cache_configs[name]


#: (parameters, pixels, spp) -> size per timed stage (:attr:`Method.stage_sizes`).
StageSizes = Callable[[Any, int, int], dict[str, float]]


def fixed_stages(*names: str) -> StageSizes:
    """Stage sizes of stages that do the same work in every frame, whatever its size
    (e.g. a visibility cache's training points): one unit each."""
    return lambda _params, _pixels, _spp: dict.fromkeys(names, 1.0)


def everywhere(_features: Any) -> tuple[bool, str]:
    """A method that renders every scene (the path-tracing methods)."""
    return True, ""


@dataclass(frozen=True)
class Knob:
    """What equal-time calibration varies for a method (jobs/protocol/calibration.py).

    ``name`` is ``'spp'`` (the frame's samples per pixel) or a parameter the
    method's ``apply(params JSON, value)`` sets; ``usable(params JSON)`` says
    whether these parameters have the knob at all (``requirement`` says when).
    ``monotone``: the frame time grows with the value, so the calibration stops
    at a candidate clearly over the budget. Unless given it is true for spp (more
    samples per pixel trace more paths) and false for any other knob (with BTH,
    a larger N_c can stop paths earlier and cost less).
    """

    name: str
    candidates: tuple[int, ...]
    apply: Callable[[dict[str, Any], int], dict[str, Any]] | None = None
    usable: Callable[[dict[str, Any]], bool] = lambda _params: True
    requirement: str = ""
    monotone: bool | None = None

    def __post_init__(self) -> None:
        if self.monotone is None:
            object.__setattr__(self, "monotone", self.name == "spp")


@dataclass(frozen=True)
class SweepRole:
    """How a caching method takes part in a sweep (jobs/sweeps/sweep.py).

    ``label`` names its series in tables and plots. ``equal_bias``: the parameters
    every adaptive equal-bias point of the method has (a termination policy that
    reads the per-pixel v1 mask; no pre-training, the sweep's snapshots are the
    training). ``point(knob_value)`` gives the parameters of an adaptive
    equal-bias point on top of those and the shared ones; ``knob_value`` is None
    except for the equal-time series. ``equal_time_against``: the method whose frame time
    this method's knob is calibrated to (the series ``<name>-equal-time``).
    """

    label: str
    equal_bias: dict[str, Any]
    point: Callable[[int | None], dict[str, Any]] = lambda _value: {}
    equal_time_against: str | None = None


@dataclass(frozen=True)
class ComparisonRun:
    """One run of a method in the method comparison (jobs/pareto/report.py, NIRC paper Fig. 7).

    ``rank`` orders runs and rows across methods; ``params`` go on top of the
    comparison's shared ones (max_depth; pre-training for methods that have it);
    ``row`` labels the equal-spp row (a 'knob' run's may use ``{chosen}``).
    ``role``: 'budget' (its frame time is the budget of the knob runs; the
    baseline's, as a TimeBudget's ``pt_spp``), 'knob' (the method's knob
    calibrated to that budget; ``unfit`` notes a budget not even the smallest
    value fits), 'matched' (the baseline gets the spp that fits its frame time)
    or '' (an equal-spp row only).
    """

    rank: int
    label: str
    row: str
    params: dict[str, Any] = field(default_factory=dict)
    spp: int = 1
    role: str = ""
    unfit: str = ""


@dataclass(frozen=True)
class Method:
    """Everything about a render method, declared at the bottom of its own module.

    Its render (or ``build``) registers the integrator plugins it loads when a render
    starts (renderers.integrators.register_plugins), so reading the registry never
    imports Mitsuba. ``build(scene, params, seed)``: (render integrator, training integrator,
    cache) of a caching method. ``requires(features)``: (applies, reason why
    not) for a scene's :class:`renderers.scenes.features.SceneFeatures`.
    ``label``: its short name in tables; ``comparison``: its runs in the method
    comparison report.
    """

    name: str
    description: str
    params: type[MethodParams]
    render: Callable[..., RenderOutput]
    version: int
    knob: Knob | None = None
    sweep: SweepRole | None = None
    build: Callable[[Any, Any, int], tuple[Any, Any, Any]] | None = None
    requires: Callable[[Any], tuple[bool, str]] = everywhere
    label: str = ""
    comparison: tuple[ComparisonRun, ...] = ()
    #: Whether its expectation is the reference's (True: tested for agreement by the
    #: stress suite, docs/stress.md), not (False), or set by its ``estimator``
    #: parameter or not declared (None).
    unbiased: bool | None = None
    #: Whether its pixels share samples (spatial reuse): then its pixels are not
    #: independent, and agreement is tested per pixel and on the image mean over
    #: seeds (metrics.statistics.image_mean_test), not with the tile test.
    correlated_pixels: bool = False
    #: The size of each timed stage of a frame of ``pixels`` pixels at ``spp``: the unit
    #: its time grows with (the per-stage cost model, jobs/costs/cost_model.py). A
    #: stage it does not name grows with pixels x spp.
    stage_sizes: StageSizes = lambda _params, _pixels, _spp: {}
    #: The parameters with the method's per-frame floors (work held at a fixed size in
    #: small frames, e.g. training records) scaled by a factor, so that the cost model can
    #: measure what a unit of a floored stage costs; None: the method has no floors.
    scale_floors: Callable[[Any, float], Any] | None = None
    #: Whether its frames share samples (temporal reuse): then one seed's frames are
    #: positively correlated, their spread understates the variance of their mean, and
    #: the per-cache rBias^2 / rVar of a run (which take them as independent) are not
    #: reported (jobs.protocol.executor.per_cache_metrics).
    correlated_frames: bool = False

    def applies_to(self, features: Any) -> tuple[bool, str]:
        """Whether the method can render a scene with ``features``, and why not."""
        return self.requires(features)

    def shared_params(self, max_depth: int, pretrain_frames: int) -> dict[str, Any]:
        """The parameters all of a comparison's runs of this method share: the depth, and
        the pre-training frames where the method has them (report, pareto)."""
        shared: dict[str, Any] = {"max_depth": max_depth}
        if "pretrain_frames" in self.params.model_fields:
            shared["pretrain_frames"] = pretrain_frames
        return shared


@dataclass
class RenderOutput:
    """What a method returns for one seed."""

    accumulated: np.ndarray                 # (H, W, 3) float32 mean of all frames
    frames: list[np.ndarray] | None         # per-frame images when requested
    timings: dict[str, Any]                 # see renderers.timing.summarize
    path_stats: dict[str, Any] = field(default_factory=dict)
    method_stats: dict[str, Any] = field(default_factory=dict)  # e.g. loss curve, cache config
    #: (H, W, 3) sample variance of the residual estimator at the primary hit, NaN where
    #: unknown (metrics.residual_variance); None for a method without one
    residual_variance: np.ndarray | None = None


#: Renders frame ``index`` with ``seed``, timing its stages with ``timer``;
#: returns the frame's film tensor (RGB first, then the method's AOVs).
FrameFn = Callable[[int, int, StageTimer], Any]

#: Called after frame ``index`` (untimed) with that frame's RGB and the running mean.
OnFrame = Callable[[int, np.ndarray, np.ndarray], None]


@dataclass(frozen=True)
class FrameHooks:
    """What a caller wants from the frame loop besides the accumulated image.

    ``keep_frames``: return every frame's RGB; ``progress(done, total)`` after
    each frame; ``on_frame`` after each frame (e.g. the executor's per-frame
    error against the reference: the convergence curve); ``warmup``: render
    the untimed warm-up frame first (a caller that renders several series
    with one already-compiled integrator warms up once and passes False);
    ``kernel_every``: every how many timed frames one is a kernel frame, recording
    Dr.Jit's kernel history for the kernel time of every stage, between wall frames
    timed without it (renderers.timing.frame_kind): 4 by default; 1 (every frame) and
    0 (none) only to measure what recording the history costs; 2 is refused (it leaves
    no wall frame after the first). ``first_frame``: the place of this loop's first
    timed frame in that schedule, so that a run of several seeds continues it from
    seed to seed (the executor passes seed index x frames): a run of one frame per
    seed then still has kernel frames, and its pooled timings (renderers.timing.pooled)
    take wall times from some seeds and kernel times from others. ``before_frame(index)``
    before each timed frame, outside its time (an animation's scene update, which its
    caller times as a stage of its own: jobs.protocol.animation).
    """

    keep_frames: bool = False
    progress: Callable[[int, int], None] | None = None
    on_frame: OnFrame | None = None
    warmup: bool = True
    kernel_every: int = KERNEL_EVERY
    first_frame: int = 0
    before_frame: Callable[[int], None] | None = None

    def __post_init__(self) -> None:
        if self.kernel_every < 0 or self.kernel_every == 2:
            raise ValueError("kernel_every must be 0, 1 or at least 3 (2 leaves no wall "
                             f"frame after the first), not {self.kernel_every}")


class FrozenRender:
    """A frame that is one frozen ``mi.render`` (renderers.frozen), timed as 'render': the
    seed and the integrator's ``frame_state`` (asked anew every frame) are its
    arguments. Built only while freezing is on."""

    def __init__(self, scene: Any, integrator: Any, spp: int) -> None:
        import mitsuba as mi

        self.scene = scene.scene
        self.seed_type = mi.UInt32
        self.integrator = integrator

        def render(scene: Any, seed: Any, state: dict[str, Any]) -> Any:
            integrator.bind_frame_state(scene, state)
            return mi.render(scene, integrator=integrator, spp=spp, seed=seed)

        self.render = Frozen(render)

    def __call__(self, _index: int, seed: int, timer: StageTimer) -> Any:
        with timer.stage("render"):
            # The state is asked anew every frame: a cache's weights change with training.
            state = self.integrator.frame_state(self.scene)
            image = self.render(self.scene, self.seed_type(seed), state)
            # A recording bound the integrator to its own inputs: bind the frame's again.
            self.integrator.bind_frame_state(self.scene, state)
            synchronize(image)
        return image

    def recordings(self) -> int:
        return self.render.recordings()


class WithParts:
    """A frame function made of parts (training, then a render stage) that reports the
    recordings of its frozen parts and of ``counted`` objects (a cache's frozen
    training step), so that run_frames warms it up until they settle; its
    :meth:`settle` runs the frozen frame parts alone (they change no state: a cache
    trains once in the warm-up, frozen or not)."""

    def __init__(self, frame: FrameFn, *parts: Any, counted: tuple[Any, ...] = ()) -> None:
        self.frame = frame
        self.frozen = [part for part in parts
                       if getattr(part, "recordings", lambda: None)() is not None]
        self.counted = [c for c in counted if c.recordings() is not None]
        recorded = [*self.frozen, *self.counted]
        if recorded:
            self.recordings = lambda: sum(part.recordings() for part in recorded)
            self.growth_recordings = lambda: sum(growth_recordings(part)
                                                 for part in recorded)

    def __call__(self, index: int, seed: int, timer: StageTimer) -> Any:
        return self.frame(index, seed, timer)

    def settle(self, index: int, seed: int, timer: StageTimer) -> None:
        for part in self.frozen:
            part(index, seed, timer)
        for counted in self.counted:
            counted.settle()


def growth_recordings(frame: Any) -> int:
    """Recordings a frame function made in frames whose buffers grew (0: it has none
    that grow): a caching frame's passes record anew for a larger buffer layout."""
    count = getattr(frame, "growth_recordings", 0)
    return count() if callable(count) else count


def render_stage(scene: Any, integrator: Any, spp: int) -> FrameFn:
    """A frame that is one ``mi.render`` of ``scene`` with ``integrator``, timed as 'render':
    frozen (:class:`FrozenRender`) where the integrator says its frame can be
    (``frame_freezable()``: no state read from Python objects, no host read-back).

    A caching integrator (renderers.integrators.cached, with deferred cache queries)
    renders in stages (renderers.methods.staged), frozen where it can be: 'render' is
    then path tracing only, 'inference' the deferred cache queries.
    """
    import mitsuba as mi

    if hasattr(integrator, "query_channels"):   # deferred cache queries: in stages
        from renderers.methods.staged import StagedRender

        return StagedRender(scene, integrator, spp)
    if freezing() and getattr(integrator, "frame_freezable", lambda: False)():
        return FrozenRender(scene, integrator, spp)

    def render_frame(_index: int, seed: int, timer: StageTimer):
        if hasattr(integrator, "timer"):
            integrator.timer = timer
        with timer.stage("render"):
            image = mi.render(scene.scene, integrator=integrator, spp=spp, seed=seed)
            synchronize(image)
        return image

    return render_frame


#: Per-path AOVs of the integrators and the statistic their frame mean is reported as.
AOV_STATS = {
    "depth": "avg_path_vertices",          # surface vertices per path
    "cache_depth": "avg_cache_depth",      # 1 + vertex index of termination into the cache (0: none)
    "cache_vertices": "avg_cache_vertices",  # vertices at which a cache term was added
}


class PathStats:
    """Frame means of the per-path AOVs, and (at 1 spp, where a pixel is one path)
    the fraction of paths per value of ``cache_depth``: how often each vertex used the cache,
    and (with the ``depth`` AOV) ``background_fraction``, the paths with no surface vertex
    (``cache_depth`` 0 alone does not tell them from paths that never used the cache)."""

    def __init__(self, aov_names: tuple[str, ...]) -> None:
        self.aov_names = aov_names
        self.sums = dict.fromkeys(aov_names, 0.0)
        self.histogram: dict[int, float] = {}
        self.background = 0.0   # sum over frames of the fraction of paths without a vertex
        self.frames = 0

    def add(self, aovs: np.ndarray, spp: int) -> None:
        self.frames += 1
        for index, name in enumerate(self.aov_names):
            self.sums[name] += float(np.nanmean(aovs[..., index]))
        if spp == 1 and "cache_depth" in self.aov_names:
            values = np.rint(aovs[..., self.aov_names.index("cache_depth")]).astype(int).ravel()
            for value, count in zip(*np.unique(values, return_counts=True), strict=True):
                self.histogram[int(value)] = self.histogram.get(int(value), 0.0) + count / values.size
            if "depth" in self.aov_names:
                depth = np.rint(aovs[..., self.aov_names.index("depth")])
                self.background += float(np.count_nonzero(depth == 0)) / depth.size

    def result(self) -> dict[str, Any]:
        stats: dict[str, Any] = {AOV_STATS.get(n, n): s / self.frames for n, s in self.sums.items()}
        if self.histogram:
            stats["cache_depth_fractions"] = {
                str(k): v / self.frames for k, v in sorted(self.histogram.items())}
            if "depth" in self.aov_names:
                stats["background_fraction"] = self.background / self.frames
        return stats


def run_frames(
    render_frame: FrameFn,
    *,
    seed_parts: tuple[Any, ...],
    frames: int,
    spp: int,
    aov_names: tuple[str, ...] = ("depth",),
    hooks: FrameHooks = FrameHooks(),
) -> RenderOutput:
    """The shared frame loop: warm-up, F timed frames, running mean, path statistics.

    ``seed_parts`` identify the render (scene fingerprint, method, params, seed
    index); frame f renders with ``derive_seed(*seed_parts, f)`` and the warm-up
    frame with a seed of its own, so it never correlates with a timed frame.
    Dr.Jit's kernel history is on in the kernel frames and off in the others
    (``hooks.kernel_every``; renderers.timing), and the machine's load is
    measured over the timed frames (renderers.load). A frame function with
    ``recordings()`` (frozen, renderers.frozen) warms up until its recording count has
    settled in both history states (a frozen function records in each), and the counts
    after the warm-up and after the timed frames are reported (``frozen``).
    """
    recordings = getattr(render_frame, "recordings", None)
    warmup = Warmup()
    if hooks.warmup:
        warmup = _warm_up(render_frame, seed_parts, recordings,
                          history_states(hooks.kernel_every))
    settled = recordings() if recordings else None
    grown = growth_recordings(render_frame)

    accumulated: np.ndarray | None = None
    path_stats = PathStats(aov_names)
    kept: list[np.ndarray] = []
    timed: list[FrameTime] = []
    with LoadMonitor(host_bound_cpu=host_runs_kernels()) as load:
        for index in range(frames):
            kind = frame_kind(hooks.first_frame + index, hooks.kernel_every)
            if hooks.before_frame:
                hooks.before_frame(index)
            with kernel_history(kind == KERNEL):
                timer = StageTimer()
                with timer.frame():
                    film = render_frame(index, derive_seed(*seed_parts, index), timer)
            film = np.asarray(film)
            timed.append(timer.record(kind))
            rgb = film[..., :3].astype(np.float32)
            # Running mean keeps memory constant however many frames run.
            accumulated = (rgb.copy() if accumulated is None
                           else accumulated + (rgb - accumulated) / (index + 1))
            path_stats.add(film[..., 3:], spp)
            if hooks.keep_frames:
                kept.append(rgb)
            if hooks.on_frame:
                hooks.on_frame(index, rgb, accumulated)
            if hooks.progress:
                hooks.progress(index + 1, frames)

    assert accumulated is not None
    timings = summarize(timed, warmup, load.result())
    timings["frozen"] = None if recordings is None else {
        "recordings_after_warmup": settled, "recordings_after_frames": recordings(),
        "warmup_frames": warmup.frames,
        # Of the recordings after the warm-up, those of frames whose buffers grew.
        "recordings_for_growth": growth_recordings(render_frame) - grown}
    return RenderOutput(
        accumulated=accumulated,
        frames=kept if hooks.keep_frames else None,
        timings=timings,
        path_stats=path_stats.result(),
    )


def _warm_up(render_frame: FrameFn, seed_parts: tuple[Any, ...],
             recordings: Callable[[], int] | None, states: tuple[bool, ...]) -> Warmup:
    """The untimed warm-up: one frame, then, for a frozen frame function, calls of its
    ``settle`` (the frozen parts alone, which change no state; else the frame again)
    until its recording count has held over SETTLED_CALLS calls in each kernel-history
    state of the timed frames (``states``, taken in turn: Dr.Jit records a frozen
    function anew for each), ending with a call in the last (the history off, as
    before a wall frame), at most MAX_WARMUP_FRAMES per state. So a cache trains in one
    warm-up frame whether its frames are frozen or not. The compile time is that of the
    calls with the history on (None without any)."""
    seconds, frames = 0.0, 0
    compile_s: float | None = 0.0 if any(states) else None
    before, held = -1, 0
    settle = getattr(render_frame, "settle", render_frame)
    while True:
        seed = derive_seed(*seed_parts, "warmup", *((frames,) if frames else ()))
        with kernel_history(states[frames % len(states)]):
            timer = StageTimer()
            with timer.frame():
                (settle if frames else render_frame)(-1, seed, timer)
        frames += 1
        seconds += timer.frame_s
        if timer.kernels is not None and compile_s is not None:
            compile_s += sum(k.compile_s for k in timer.kernels.values())
        held = held + 1 if recordings is not None and recordings() == before else 0
        if (recordings is None or frames >= MAX_WARMUP_FRAMES * len(states)
                or (held >= SETTLED_CALLS * len(states) and frames % len(states) == 0)):
            return Warmup(seconds, compile_s, frames)
        before = recordings()
