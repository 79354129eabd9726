"""The public result of a run: one model for the API, the CLI tables, the sweep and the report.

A stored run (jobs.record.models.Run) is shown to users in one shape only,
made by one function, :meth:`RunResult.of`:

===========================  ===============================================
model                        used by
===========================  ===============================================
:class:`RunResult`           ``GET /api/v1/results`` and ``/compare`` rows;
                             the report's rows (:class:`ReportRow` adds a
                             label); the sweep's rows
                             (jobs.sweeps.sweep.SweepRow adds its columns);
                             the pareto points (jobs.pareto.pareto.ParetoPoint)
:class:`RunResultDetail`     ``GET /api/v1/runs/{id}`` (the API adds artifact
                             URLs); the table ``nirc-bench render`` prints,
                             embedded or from a service
===========================  ===============================================

The metric fields (``mrse``, ``mrse_ci95``, ``rbias2``, ``rvar``, ``flip``,
``psnr``, ...) are generated from metrics.registry; a metric the run's quality
verdict withholds is null.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, create_model

from jobs.protocol.labels import resolved_params, run_label
from jobs.protocol.versions import is_current
from metrics.registry import LISTED, Metric, row_values

#: Keys a stored run's ``params`` holds besides the method's parameters: the spec it ran,
#: and the XML scene settings it replaced (only for an XML scene that had any).
RUN_RECORD_KEYS = ("spec", "scene_overrides")


def method_params(params: dict[str, Any] | None) -> dict[str, Any]:
    """A stored run's ``params`` without :data:`RUN_RECORD_KEYS`: what configured its
    method (resolved parameters, and a calibration or sweep point's own keys)."""
    return {k: v for k, v in (params or {}).items() if k not in RUN_RECORD_KEYS}


def _metric_fields(metrics: tuple[Metric, ...]) -> dict[str, Any]:
    """``<field>`` per listed metric (and ``<field>_ci95``), with its description."""
    fields: dict[str, Any] = {}
    for m in metrics:
        unit = f" [{m.unit}]" if m.unit else ""
        fields[m.field] = (float | None, Field(
            None, description=f"{m.description}{unit}; {m.direction} is better (stored as "
                              f"metrics.{m.key}; null when withheld or not computed)"))
        if m.ci_key:
            fields[f"{m.field}_ci95"] = (list[float] | None, Field(
                None, description=f"95 % interval of {m.label} (how: {m.field}_ci_note; "
                                  "docs/metrics.md); null with fewer than 3 seeds"))
            fields[f"{m.field}_ci_note"] = (str | None, Field(
                None, description=f"how the {m.label} interval was made, or why there is "
                                  "none"))
    fields["below_noise_floor"] = (list[str], Field(
        default_factory=list,
        description="metrics (by field) whose noise-corrected estimate is negative: the "
                    "quantity is below what the render and reference noise resolve; read "
                    "the value as indistinguishable from 0, not as a number to rank by"))
    fields["within_noise"] = (list[str], Field(
        default_factory=list,
        description="noise-corrected metrics (by field) whose 95 % interval holds 0 (or, "
                    "without an interval, whose estimate is negative): not told apart from 0"))
    fields["rbias2_basis"] = (str | None, Field(
        None, description="'per cache': rBias² is the mean of the caches' own values (a "
                          "method training a cache per seed); 'pooled': over the K renders; "
                          "null for runs stored before metric version 3"))
    fields["bias_verdict"] = (str | None, Field(
        None, description="'biased' (rBias²'s 95 % interval above 0) or 'within noise'; "
                          "null when it cannot be said"))
    return fields


#: The metric columns of a result, generated from metrics.registry.
ResultMetrics = create_model("ResultMetrics", **_metric_fields(LISTED))


def breakdown_ms(timings: dict[str, Any]) -> dict[str, float] | None:
    """The Table-1-style breakdown of the median frame in milliseconds per part (render,
    training_paths, training, inference, ..., other): its wall time (``parts_s``); None
    for runs stored before it."""
    parts = (timings.get("breakdown") or {}).get("parts_s")
    return None if parts is None else {name: 1e3 * s for name, s in parts.items()}


#: The part of a frame outside its stages (renderers.timing.OTHER, which loads Dr.Jit).
OTHER_PART = "other"


def device_split(timings: dict[str, Any]) -> dict[str, Any] | None:
    """The median (wall) frame's parts split into kernel and harness by the median kernel
    frame's shares (docs/timing.md, "Kernel and harness beside the frame time"): each
    part's kernel share of the median kernel frame (its kernel over its own wall time of
    the part, in [0, 1]) times the median frame's wall time of the part, the rest
    harness. So a part's kernel + harness is its wall time and the stages' kernel time
    never exceeds the frame time, however slow the kernel frames were. Returns
    ``kernel_ms`` and ``harness_ms`` per part, the stages' ``kernel_s`` and its
    ``harness_share`` of their wall time; None for runs stored without kernel time."""
    frame = timings.get("breakdown") or {}
    wall, kernel = frame.get("parts_s"), frame.get("kernel_parts_s")
    if not wall or kernel is None:
        return None
    harness = frame.get("harness_parts_s")
    # The kernel frame's own wall time of each part (runs stored before harness parts:
    # their kernel parts are the median frame's own).
    kernel_frame = ({name: kernel.get(name, 0.0) + harness.get(name, 0.0) for name in kernel}
                    if harness is not None else wall)
    kernel_s = {name: seconds * _share(kernel.get(name, 0.0), kernel_frame.get(name, 0.0))
                for name, seconds in wall.items()}
    stages = [name for name in wall if name != OTHER_PART]
    stage_wall = sum(wall[name] for name in stages)
    stage_kernel = sum(kernel_s[name] for name in stages)
    return {"kernel_ms": {name: 1e3 * s for name, s in kernel_s.items()},
            "harness_ms": {name: 1e3 * (wall[name] - s) for name, s in kernel_s.items()},
            "kernel_s": stage_kernel,
            "harness_share": 1.0 - stage_kernel / stage_wall if stage_wall > 0 else None}


def _share(part: float, whole: float) -> float:
    """``part`` over ``whole``, in [0, 1] (0 where ``whole`` is not positive)."""
    return min(max(part / whole, 0.0), 1.0) if whole > 0 else 0.0


def timing_flags(timings: dict[str, Any]) -> list[str]:
    """Why a run's timing may not be trusted: the machine was loaded while it was timed."""
    load = timings.get("load") or {}
    return [f"loaded: {reason}" for reason in load.get("reasons", [])] if load.get("loaded") \
        else []


def render_seconds(timings: dict[str, Any]) -> float | None:
    """Median seconds of a frame's render stage (the frame time for a method without stages)."""
    render = (timings.get("stages") or {}).get("render") or {}
    return render.get("median_s", timings.get("seconds_per_frame"))


class RunResult(ResultMetrics):
    """A stored run as users see it: what ran, where, how fast, and its listed metrics."""

    id: int
    created_at: datetime
    name: str | None = Field(None, description="the label a user gave the run")
    tags: dict[str, str] = Field(default_factory=dict, description="key=value tags a user "
                                                                   "gave the run")
    scene: str
    scene_fingerprint: str
    method: str
    method_label: str = Field("", description="what defines the run: the method and its resolved "
                                              "parameters not at their default, with a sweep "
                                              "point's eps, e.g. 'nirc (adaptive, N_c 1,1, eps "
                                              "0.3)' (jobs/protocol/labels.py)")
    params: dict[str, Any] = Field(description="the method's parameters as resolved (every "
                                               "default filled in), with a sweep point's or a "
                                               "calibration's own keys")
    scene_overrides: list[str] = Field(
        default_factory=list, description="what the scene's XML file sets that the run "
                                          "replaced (film size, integrator, max_depth, "
                                          "sampler spp), one line each")
    resolution: list[int]
    spp: int
    frames: int
    seeds: int
    seconds_per_frame: float | None = Field(
        description="median seconds per frame (a caching method's include its online training)")
    render_seconds_per_frame: float | None = Field(
        None, description="median seconds of a frame's render stage alone")
    time_breakdown_ms: dict[str, float] | None = Field(
        None, description="milliseconds of each part (render, training_paths, training, "
                          "inference, other) of the median frame, as in the NIRC paper's "
                          "Table 1; they add up to its wall time")
    kernel_breakdown_ms: dict[str, float] | None = Field(
        None, description="kernel milliseconds of each part of the median frame: its wall "
                          "time of the part times the part's kernel share of the median "
                          "kernel frame (Dr.Jit's kernel history; docs/timing.md)")
    harness_breakdown_ms: dict[str, float] | None = Field(
        None, description="harness milliseconds of each part of the median frame: its wall "
                          "time less its kernel milliseconds (host work, tracing, launch "
                          "gaps)")
    kernel_seconds_per_frame: float | None = Field(
        None, description="kernel seconds of the median frame's stages (the kernel parts "
                          "but 'other'; at most seconds_per_frame; null for runs stored "
                          "before kernel time was measured)")
    harness_share: float | None = Field(
        None, description="share of the median frame's stage time outside kernels: "
                          "1 - kernel_seconds_per_frame / seconds_per_frame")
    timing_flags: list[str] = Field(
        default_factory=list, description="why the timing may not be trusted (a loaded "
                                          "machine)")
    device_key: str
    git_commit: str | None = Field(None, description="commit of the code that made the run "
                                                     "('-dirty': with uncommitted changes)")
    git_branch: str | None = Field(None, description="branch of the commit, when known")
    quality: dict[str, Any]
    ref_floor_ratio_rbias2: float | None = Field(
        None, description="reference noise floor mean Var[R]/(R^2+eps) over |rBias^2|")
    ref_floor_ratio_mrse: float | None = Field(
        None, description="reference noise floor over |MRSE less the floor|")
    warnings: list[str] = Field(
        default_factory=list, description="e.g. the reference floor is above 10 % of a metric")
    verdict: str | None = Field(
        None, description="quality verdict (ok, undertrained-cache, untrained-cache, "
                          "nonfinite-value, nonfinite, negative-radiance, degenerate-reference, "
                          "no-emitter); null for runs stored before verdicts")
    withheld: list[str] = Field(
        default_factory=list, description="metrics the verdict makes meaningless (null above)")
    estimator_version: int
    metric_version: int
    current: bool = Field(description="computed by today's estimator and metric versions")

    @classmethod
    def fields_of(cls, run: Any) -> dict[str, Any]:
        """The field values of the stored ``run`` (jobs.record.models.Run)."""
        m, q = run.metrics, run.quality
        split = device_split(run.timings) or {}
        return {
            **row_values(m), "id": run.id, "created_at": run.created_at,
            "name": run.name, "tags": run.tags or {},
            "scene": run.scene_name, "scene_fingerprint": run.scene_fingerprint,
            "method": run.method, "method_label": run_label(run.method, run.params),
            "params": resolved_params(run.method, method_params(run.params)),
            "scene_overrides": run.params.get("scene_overrides") or [],
            "resolution": [run.width, run.height], "spp": run.spp, "frames": run.frames,
            "seeds": run.seeds, "seconds_per_frame": run.timings.get("seconds_per_frame"),
            "render_seconds_per_frame": render_seconds(run.timings),
            "time_breakdown_ms": breakdown_ms(run.timings),
            "kernel_breakdown_ms": split.get("kernel_ms"),
            "harness_breakdown_ms": split.get("harness_ms"),
            "kernel_seconds_per_frame": split.get("kernel_s"),
            "harness_share": split.get("harness_share"),
            "timing_flags": timing_flags(run.timings),
            "device_key": run.device_key, "git_commit": run.git_commit,
            "git_branch": run.git_branch, "quality": q, "verdict": q.get("verdict"),
            "withheld": q.get("withheld", []), "estimator_version": run.estimator_version,
            "metric_version": run.metric_version,
            "current": is_current(run.method, run.estimator_version, run.metric_version),
            "ref_floor_ratio_rbias2": m.get("ref_floor_ratio_rbias2"),
            "ref_floor_ratio_mrse": m.get("ref_floor_ratio_mrse"),
            "warnings": m.get("warnings") or [],
        }

    @classmethod
    def of(cls, run: Any, **extra: Any) -> RunResult:
        """The public result of the stored ``run``; ``extra``: a subclass's own fields."""
        return cls(**cls.fields_of(run), **extra)


class SeedRow(BaseModel):
    """One seed's metrics and timings (as stored)."""

    seed: int
    metrics: dict[str, Any]
    timings: dict[str, Any]


class ReferenceInfo(BaseModel):
    """The converged reference a run was scored against."""

    id: int
    spp: int
    key: str
    integrator: str | None = Field(None, description="'path' (Mitsuba's) or 'pt' (ours)")
    max_depth: int | None = Field(None, description="longest path in segments (-1: unbounded)")
    passes: int | None = None
    rel_stderr: float | None = Field(None, description="relative standard error reached")
    split_half: dict[str, Any] = Field(
        default_factory=dict, description="split-half estimate of the reference's own error")


class RunResultDetail(RunResult):
    """A run with every stored metric (per seed and aggregated), timings and provenance."""

    metrics: dict[str, Any]
    timings: dict[str, Any]
    path_stats: dict[str, Any]
    device: dict[str, Any]
    versions: dict[str, Any]
    reference_id: int | None
    reference: ReferenceInfo | None = None
    caches: dict[str, Any] = Field(
        default_factory=dict,
        description="each cache's resolved configuration, under the parameter that "
                    "overrides it ('cache', 'env_cache'): 'config', the whole network after "
                    "preset and overrides (encodings, MLP, output, loss, optimizer, EMA, "
                    "batch, steps), and 'per_frame', its training per frame (paths or "
                    "points, steps, batch size, records); empty for a method without a cache")
    per_seed: list[SeedRow]

    @classmethod
    def fields_of(cls, run: Any) -> dict[str, Any]:
        ref = run.reference
        return {
            **RunResult.fields_of(run), "metrics": run.metrics, "timings": run.timings,
            "path_stats": run.path_stats, "device": run.device, "versions": run.versions,
            "reference_id": run.reference_id,
            "reference": None if ref is None else ReferenceInfo(
                id=ref.id, spp=ref.spp, key=ref.key, integrator=ref.integrator,
                max_depth=ref.max_depth, passes=ref.passes, rel_stderr=ref.rel_stderr,
                split_half=ref.split_half or {}),
            "caches": resolved_caches(run.seed_results),
            "per_seed": [SeedRow(seed=s.seed, metrics=s.metrics, timings=s.timings)
                         for s in run.seed_results],
        }


def resolved_caches(seed_results: Any) -> dict[str, Any]:
    """The caches' resolved configuration a run stored with its seeds (the same for
    every seed: it depends on the parameters and the frame size only). Runs stored
    before ``method_stats['caches']`` kept the config and the training budget apart."""
    if not seed_results:
        return {}
    stats = seed_results[0].metrics.get("method_stats") or {}
    if "caches" in stats:
        return stats["caches"]
    if "cache_config" in stats:
        return {"cache": {"config": stats["cache_config"],
                          "per_frame": stats.get("training_budget")}}
    return {}


class ReportRow(RunResult):
    """A row of the method comparison (jobs.pareto.report): a run under its label."""

    model_config = ConfigDict(extra="ignore")

    label: str
    note: str = ""


class Skipped(BaseModel):
    """A method a scene rules out (its ``applies_to``), with the reason."""

    method: str
    reason: str
    label: str | None = Field(None, description="the row it would have had (a report's)")
