"""Time against error as the headline: every method's points on one error-vs-time plane.

``nirc-bench pareto`` renders two PT series at several spp, the paper's PT (``pt``'s
defaults: fixed Russian roulette) and the strongest PT (the lower envelope of the
path-tracing core's methods with throughput roulette), and every other method of
the registry at several values of its equal-time knob (biased NIRC's N_c), plus its
comparison runs that are not on that knob's curve (NRC, NIRC unbiased), as planned
by jobs.pareto.plan; a method with neither is skipped, and so
is one whose ``applies_to`` rules the scene out (with the reason). Every point is a run
through the executor, stored against the same reference under the point's key
(:func:`point_key`: its RenderSpec's content address with today's estimator
and metric versions, the scene fingerprint, the reference and the device): a
point already stored under its key is reused, not rendered again, so repeating
a call renders nothing new (its timing rounds are still measured, below).

Each point's seconds per frame, online training included (the caches' frame
loop trains before every frame; one-off pre-training is not per-frame time),
is the (lower) median of its timing samples: ``timing_rounds`` probes measured after
all runs in interleaved rounds (jobs.protocol.calibration), so that a drift or
a load spike of a shared machine hits every point alike, not the points that
happened to run then; with no rounds, every timed frame of the run's seeds (their
lower median is the run's stored ``seconds_per_frame``, kept with every point). [min,
max] of the samples is its spread; a spread above :data:`MAX_SPREAD` of the median,
a probe on a loaded machine (renderers.load) and a PT series whose frame time does
not grow with spp are flagged. A point timed on a loaded machine (any of its samples)
is marked ``loaded`` and left out of the fronts, the baselines' curves and the speed-ups
(listed in ``left_out`` with the reason) unless the spec allows loaded timings
(``--allow-loaded``). With ``project_res`` every point's per-stage cost
model (jobs.costs.cost_model) is measured too and its frame time projected to
that resolution: a projection from this device, beside the errors measured at the
point's own resolution. Then, for MRSE and FLIP: the Pareto front over all
points, and for every point outside the baseline its speed-up at equal error over the
baseline (the strongest PT unless the spec names another) with a bootstrap interval
over seeds and timing samples (jobs.pareto.tradeoff; docs/pareto.md). A point is a :class:`ParetoPoint`:
the public result of its stored run (jobs.protocol.results.RunResult) with
these columns.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from statistics import median_low
from typing import Any

import numpy as np
from pydantic import Field, create_model

from jobs.costs import cost_model
from jobs.pareto.plan import (
    BASELINE_LABELS,
    PAPER_PT,
    STRONGEST_PT,
    STRONGEST_PT_PARAMS,
    ParetoSpec,
    Planned,
    baseline_label,
    baseline_series,
    interleave,
    plan,
    run_spec,
)
from jobs.pareto.tradeoff import (
    BOOTSTRAP_METHOD,
    ENVELOPE_DEFINITION,
    Sample,
    Speedup,
    bootstrap_speedup,
    sample_curves,
)
from jobs.protocol.calibration import (
    DEFAULT_MAX_SPREAD,
    interleaved_rounds,
    probe_timings,
)
from jobs.protocol.executor import Prepared, execute, prepare
from jobs.protocol.job import RenderJob
from jobs.protocol.results import RunResult
from jobs.protocol.scene_store import load_spec_scene
from jobs.protocol.spec import RenderSpec
from jobs.record.config import Settings
from jobs.record.store import DuplicateKeyError, Store
from jobs.views.envelope import Curve, envelope_line, envelope_pieces
from jobs.views.front import pareto_front
from jobs.views.plots import plot_pareto
from metrics.registry import BY_NAME, Metric
from renderers.methods import BASELINE, METHODS, NotApplicable
from renderers.methods.pt import PTParams
from renderers.seeding import digest
from renderers.timing import FrameTime, merge_loads, wall_frames

#: The errors plotted against time, and the speed-up measured at (their ``field`` names).
PARETO_METRICS: tuple[Metric, ...] = (BY_NAME["mrse"], BY_NAME["flip_hdr"])
#: A point's timing samples may spread (max - min) this much of their median unflagged.
MAX_SPREAD = DEFAULT_MAX_SPREAD

Progress = Callable[[str, int, int], None]


@dataclass
class Timing:
    """A point's timing samples (seconds per frame), the machine's load during each of
    its probes, and its projection to another resolution (if asked for)."""

    samples: list[float]
    loads: list[dict[str, Any] | None] = field(default_factory=list)
    interleaved: bool = True        # samples of interleaved probes, not a run's frames
    projection: cost_model.Projection | None = None
    #: Per sample, the wall seconds of each stage of the frame the sample is (the
    #: probe's median frame, or the run's frame); empty where the run kept none.
    parts: list[dict[str, float]] = field(default_factory=list)

    def without(self, stage: str) -> list[float] | None:
        """The samples less the frame's ``stage`` (None where a sample's frame has no
        such stage or its stages are not known)."""
        if len(self.parts) != len(self.samples) or not all(
                parts.get(stage, 0.0) > 0.0 for parts in self.parts):
            return None
        return [sample - parts[stage]
                for sample, parts in zip(self.samples, self.parts, strict=True)]

    def loaded(self) -> bool:
        """Whether other work held the CPU while any of the samples was taken."""
        load = merge_loads(self.loads)
        return bool(load and load["loaded"])

    def flags(self) -> list[str]:
        """Why these samples may not be trusted (the module docstring)."""
        found = []
        middle = float(np.median(self.samples))
        spread = (max(self.samples) - min(self.samples)) / middle if middle > 0 else 0.0
        if self.interleaved and len(self.samples) > 1 and spread > MAX_SPREAD:
            found.append(f"its timing samples spread {100 * spread:.0f} % of their median "
                         f"(bound {100 * MAX_SPREAD:.0f} %)")
        load = merge_loads(self.loads)
        if load and load["loaded"]:
            found.append("machine loaded while it was timed: " + "; ".join(load["reasons"]))
        return found


def _metric_columns() -> dict[str, Any]:
    """Per error of :data:`PARETO_METRICS`: its per-seed values, front flag and speed-up."""
    columns: dict[str, Any] = {}
    for m in PARETO_METRICS:
        columns[f"{m.field}_per_seed"] = (list[float | None], Field(
            description=f"{m.label} of each seed (the bootstrap resamples them)"))
        columns[f"front_{m.field}"] = (bool, Field(
            False, description=f"on the Pareto front of {m.label} against seconds_per_frame"))
        columns[f"speedup_{m.field}"] = (Speedup | None, Field(
            None, description=f"speed-up at equal {m.label} over the baseline with its "
                              "bootstrap 95 % interval (null for a baseline point)"))
    return columns


#: RunResult with the per-metric columns of a point, generated from PARETO_METRICS.
_ParetoColumns = create_model("_ParetoColumns", __base__=RunResult, **_metric_columns())


class ParetoPoint(_ParetoColumns):  # type: ignore[misc,valid-type]
    """A point of the error-vs-time plane: the public result of its stored run
    (jobs.protocol.results.RunResult, ``id`` is the run's) with the pareto columns.

    ``seconds_per_frame`` is the point's time, the median of its timing samples
    (the module docstring); the run's own stored frame time is
    ``run_seconds_per_frame``. Every other RunResult field is the run's.
    """

    series: str = Field(description="the series' label (a method, or one of its comparison runs)")
    label: str = Field(description="the point's label (series and knob value)")
    baseline: bool = Field(description="a point of the baseline the speed-ups are measured over")
    named_baseline: str = Field(
        "", description="the named PT baseline its series is ('paper-pt') or is a candidate "
                        "of ('strongest-pt'); '' for any other series")
    reused: bool = Field(description="the run was stored by an earlier call, not rendered now")
    seconds_per_frame: float = Field(
        description="lower median of the timing samples: seconds per frame, online training "
                    "included")
    seconds_spread: list[float] = Field(description="[min, max] of the timing samples")
    timing_samples: list[float] = Field(
        description="one per interleaved timing round (without rounds, every timed frame of "
                    "the run's seeds; older runs: each seed's frame time)")
    run_seconds_per_frame: float | None = Field(
        description="the stored run's seconds per frame (its median frame over all seeds)")
    probe_flags: list[str] = Field(
        default_factory=list, description="why this point's timing samples may not be "
                                          "trusted: a spread above the bound, a loaded machine")
    projection: dict[str, Any] | None = Field(
        None, description="its frame time projected to another resolution from this "
                          "device's per-stage cost model (jobs.costs.cost_model)")
    without_stages: list[str] = Field(
        default_factory=list,
        description="stages taken out of its time (--without-stage): not the method's whole "
                    "cost, so never on a front; empty for a measured point")
    loaded: bool = Field(
        False, description="a timing sample was taken on a loaded machine (renderers.load): "
                           "off the fronts, the baselines and the speed-ups unless "
                           "--allow-loaded")

    @classmethod
    def measured(cls, planned: Planned, run: Any, timing: Timing, reused: bool) -> ParetoPoint:
        """The point of ``planned`` from its stored ``run`` and its ``timing`` (whether it
        is a baseline point is :func:`_evaluate`'s to say)."""
        fields = cls.fields_of(run)
        seeds = sorted(run.seed_results, key=lambda s: s.seed)
        seconds = timing.samples
        return cls(**{
            **fields, "series": planned.series, "label": planned.label,
            "baseline": False, "named_baseline": planned.named, "reused": reused,
            "seconds_per_frame": float(median_low(seconds)),
            "seconds_spread": [min(seconds), max(seconds)], "timing_samples": seconds,
            "run_seconds_per_frame": fields["seconds_per_frame"],
            "probe_flags": timing.flags(), "loaded": timing.loaded(),
            "projection": None if timing.projection is None else timing.projection.to_json(),
            **{f"{m.field}_per_seed": [s.metrics.get(m.seed_key) for s in seeds]
               for m in PARETO_METRICS}})


@dataclass
class ParetoResult:
    spec: ParetoSpec
    device: str
    reference_id: int
    points: list[ParetoPoint]
    skipped: list[dict[str, str]]
    timing: dict[str, Any]
    #: Points left out of the fronts, baselines and speed-ups, each with the reason.
    left_out: list[dict[str, str]]
    bootstrap: dict[str, Any]
    baselines: dict[str, Any] = field(default_factory=dict)
    work: dict[str, int] = field(default_factory=dict)
    files: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The JSON of ``--json`` and pareto.json: each point is ``ParetoPoint.model_dump``."""
        return {**{k: v for k, v in asdict(self).items() if k != "points"},
                "points": [p.model_dump(mode="json") for p in self.points]}


def point_key(spec: RenderSpec, prepared: Prepared) -> str:
    """The idempotency key a point's run is stored under: what determines it (the
    RenderSpec's content address with today's estimator and metric versions, the
    scene's fingerprint, the reference and the device, whose frame times it stores)."""
    return digest("pareto-point", spec.key(), prepared.scene.fingerprint,
                  prepared.reference.key, prepared.device["device_key"], length=32)


def stored_or_rendered(job: RenderJob, prepared: Prepared, store: Store, settings: Settings,
                       progress: Progress | None = None) -> tuple[Any, bool]:
    """The stored run of ``job`` under its spec's :func:`point_key` and True, or the run
    rendered now (jobs.protocol.executor.execute) and False."""
    key = point_key(job.spec, prepared)
    run = store.find_run_by_idempotency_key(key)
    if run is not None:
        return run, True
    try:
        summary = execute(job, store, settings, progress=progress, idempotency_key=key)
    except DuplicateKeyError as err:   # another call stored it meanwhile
        return err.existing, True
    return store.get_run(summary.run_id), False


def run_pareto(spec: ParetoSpec, store: Store, settings: Settings,
               progress: Progress | None = None, out_dir: Path | None = None) -> ParetoResult:
    """Render (or reuse), time and evaluate every planned point (module docstring)."""
    series, skipped = plan(spec)
    # Each point's job, parsed once: rendered, timed in every round and modelled from it.
    jobs = {id(point): RenderJob.parse(run_spec(spec, point))
            for points in series for point in points}
    prepared = prepare(jobs[id(series[0][0])], store, settings, progress)
    runs: list[tuple[Planned, Any, bool]] = []
    not_applicable: set[str] = set()
    ordered = interleave(series)
    for index, point in enumerate(ordered):
        if point.method in not_applicable:
            continue
        if progress:
            progress("points", index, len(ordered))
        step = (lambda stage, done, total, label=point.label:
                progress(f"{label}: {stage}", done, total)) if progress else None
        try:
            runs.append((point, *stored_or_rendered(jobs[id(point)], prepared, store,
                                                    settings, progress=step)))
        except NotApplicable as err:
            not_applicable.add(point.method)
            skipped.append({"method": point.method, "reason": str(err)})
    if progress:
        progress("points", len(ordered), len(ordered))

    timings, order = _timing_samples(runs, jobs, prepared.scene, spec, progress)
    # The probes load each resolution in turn: no other scene may stay alive meanwhile
    # (cost_model.SceneSlot).
    prepared = replace(prepared, scene=None)
    if spec.project_res is not None:
        _project(runs, jobs, timings, spec, prepared, settings, progress)
    rank = {id(p): i for i, p in enumerate(p for points in series for p in points)}
    ranked = sorted(enumerate(runs), key=lambda item: rank[id(item[1][0])])
    points = [ParetoPoint.measured(planned, run, timings[i], reused)
              for i, (planned, run, reused) in ranked]
    measured = list(points)
    without = {}
    for stage in spec.without_stages:
        derived = without_stage_points(measured, [timings[i] for i, _ in ranked], stage)
        without[stage] = [p.label for p in derived]
        points += derived
    left_out = _evaluate(points, spec.resamples, spec.baseline, spec.allow_loaded)
    reused = sum(p.reused for p in points)
    result = ParetoResult(
        spec=spec, device=prepared.device["device_key"], reference_id=prepared.reference.id,
        points=points, skipped=skipped, left_out=left_out,
        timing={"rounds": spec.timing_rounds, "probe_frames": spec.probe_frames,
                "samples": ("one per interleaved round" if spec.timing_rounds else
                            "the run's timed frames"),
                "max_spread": MAX_SPREAD, "flags": baseline_flags(points),
                "run_order": [planned.label for planned, _, _ in runs], "round_order": order,
                "cost_resolutions": spec.cost_resolutions if spec.project_res else None,
                "without_stages": without},
        bootstrap={"method": BOOTSTRAP_METHOD, "resamples": spec.resamples,
                   "confidence": 0.95},
        baselines=baselines(points, spec.baseline, spec.allow_loaded),
        work={"reference_rendered": int(prepared.reference.rendered_now),
              "points_rendered": len(points) - reused, "points_reused": reused,
              "timing_probes": spec.timing_rounds * len(points)})
    if out_dir is not None:
        result.files = write_outputs(result, out_dir)
    return result


def _timing_samples(runs: list[tuple[Planned, Any, bool]], jobs: dict[int, RenderJob],
                    scene: Any, spec: ParetoSpec,
                    progress: Progress | None) -> tuple[list[Timing], list[str]]:
    """Per run: its ``timing_rounds`` interleaved probes (without rounds, its per-seed
    frame times) with their loads; and the order of the probes."""
    total, done = spec.timing_rounds * len(runs), 0

    def measure(index: int) -> dict[str, Any]:
        nonlocal done
        planned = runs[index][0]
        timings = probe_timings(scene, planned.method, jobs[id(planned)].params, planned.spp,
                                spec.probe_frames)
        done += 1
        if progress:
            progress("timing rounds", done, total)
        return timings

    timed = interleaved_rounds(list(range(len(runs))), measure, spec.timing_rounds,
                               name=lambda i: runs[i][0].label)
    found = []
    for index, (_, run, _) in enumerate(runs):
        probes = timed.times[index]
        if probes:
            found.append(Timing([p["frame_median_s"] for p in probes],
                                [p.get("load") for p in probes],
                                parts=[p["breakdown"]["parts_s"] for p in probes]))
        else:
            samples, parts = stored_frame_times(run)
            found.append(Timing(samples, [(run.timings or {}).get("load")],
                                interleaved=False, parts=parts))
    return found, timed.order


def stored_frame_times(run: Any) -> tuple[list[float], list[dict[str, float]]]:
    """The frame times of a stored run and each frame's stage seconds: every wall frame
    (renderers.timing.wall_frames) of every seed (whose lower median is the run's
    ``seconds_per_frame``), or for runs stored before frames were kept, each seed's frame
    time (its stages unknown: none)."""
    seeds = sorted(run.seed_results, key=lambda s: s.seed)
    if all("frames_detail" in (s.timings or {}) for s in seeds):
        frames = wall_frames([FrameTime.from_json(f)
                              for s in seeds for f in s.timings["frames_detail"]])
        return [f.total_s for f in frames], [f.stages for f in frames]
    return [s.metrics["seconds_per_frame"] for s in seeds], []


def without_stage_points(points: list[ParetoPoint], timings: list[Timing],
                         stage: str) -> list[ParetoPoint]:
    """Per point whose every timing sample's frame ran ``stage``: the point again with
    the stage's seconds taken out of its samples, in a series of its own ("<series>
    without <stage>"). Not the method's cost (a stage it cannot do without): off the
    fronts, beside the point (e.g. grid-cache's propagation pass, which [VTT24] Table 1
    reports apart)."""
    derived = []
    for point, timing in zip(points, timings, strict=True):
        samples = timing.without(stage)
        if samples is None:
            continue
        derived.append(point.model_copy(update={
            "series": f"{point.series} without {stage}",
            "label": f"{point.label} without {stage}", "named_baseline": "",
            "without_stages": [*point.without_stages, stage],
            "seconds_per_frame": float(median_low(samples)),
            "seconds_spread": [min(samples), max(samples)], "timing_samples": samples}))
    return derived


def _project(runs: list[tuple[Planned, Any, bool]], jobs: dict[int, RenderJob],
             timings: list[Timing], spec: ParetoSpec, prepared: Prepared, settings: Settings,
             progress: Progress | None) -> None:
    """Measure each point's per-stage cost model at ``spec.cost_resolutions`` and project
    its frame time to ``spec.project_res`` (jobs.costs.cost_model)."""
    assert spec.project_res is not None
    scene_at = cost_model.SceneSlot(lambda res: load_spec_scene(spec.scene, res, settings))
    for index, ((planned, _, _), timing) in enumerate(zip(runs, timings, strict=True)):
        method = METHODS[planned.method]

        def render(res: int, params: Any, spp: int, method: str = planned.method
                   ) -> dict[str, Any]:
            return probe_timings(scene_at(res), method, params, spp, spec.probe_frames)

        step = (lambda done, total, label=planned.label, index=index:
                progress(f"cost model {index + 1}/{len(runs)} ({label})", done, total)
                ) if progress else None
        model = cost_model.measure(method, jobs[id(planned)].params,
                                   planned.spp, prepared.device["device_key"], render,
                                   resolutions=spec.cost_resolutions,
                                   rounds=max(spec.timing_rounds, 1), progress=step)
        timing.projection = model.project(*spec.project_res)


def baseline_flags(points: list[ParetoPoint]) -> list[str]:
    """A PT or baseline series whose frame time does not grow with spp: its timings are
    noisier than the steps between them (the speed-ups interpolate along its curve)."""
    flags = []
    for series in dict.fromkeys(p.series for p in points if p.baseline or p.named_baseline):
        curve = sorted((p.spp, p.seconds_per_frame) for p in points if p.series == series)
        flags += [f"{series} is not monotone in spp: {a} spp {1e3 * ta:.3g} ms/frame >= "
                  f"{b} spp {1e3 * tb:.3g} ms/frame (timing noise above the step; re-run "
                  "quiet or with more --timing-rounds)"
                  for (a, ta), (b, tb) in zip(curve, curve[1:], strict=False) if ta >= tb]
    return flags


LOADED_REASON = ("timed on a loaded machine (renderers.load): left out of the fronts, the "
                 "baselines and the speed-ups (--allow-loaded uses it)")


def timed_quietly(point: ParetoPoint, allow_loaded: bool) -> bool:
    """Whether ``point``'s time may be compared: not loaded, or loaded timings allowed."""
    return allow_loaded or not point.loaded


def _baseline_samples(points: list[ParetoPoint], key: str,
                      baseline: Callable[[ParetoPoint], bool]) -> dict[str, list[Sample]]:
    """Per series of the points ``baseline`` selects: its samples with the error ``key``,
    for the series with at least two (a curve is interpolated between its points)."""
    found: dict[str, list[Sample]] = {}
    for point in points:
        if baseline(point) and _usable(point, key):
            found.setdefault(point.series, []).append(_sample(point, key))
    return {series: samples for series, samples in found.items() if len(samples) >= 2}


def _evaluate(points: list[ParetoPoint], resamples: int, baseline: str,
              allow_loaded: bool = False) -> list[dict[str, str]]:
    """Mark the points of the series ``baseline`` names (jobs.pareto.plan.baseline_series),
    each metric's front, and the other points' speed-ups at equal error over that
    baseline: the lower envelope of its series' curves (jobs.pareto.tradeoff). Points
    timed on a loaded machine take part in none of them unless ``allow_loaded``; they
    are returned with the reason (label, reason)."""
    counts = Counter((p.series, p.named_baseline) for p in points)
    chosen = baseline_series(baseline, [(s, n, c) for (s, n), c in counts.items()])
    against = baseline_label(baseline)
    for point in points:
        point.baseline = point.series in chosen
    for metric in PARETO_METRICS:
        key = metric.field
        # A method's whole cost, timed on a quiet machine (or loaded timings allowed).
        whole = [p for p in points if not p.without_stages and timed_quietly(p, allow_loaded)]
        front = pareto_front([p.seconds_per_frame for p in whole],
                             [getattr(p, key) for p in whole])
        for point in points:
            setattr(point, f"front_{key}", False)
        for point, on in zip(whole, front, strict=True):
            setattr(point, f"front_{key}", on)
        baseline = _baseline_samples(
            points, key, lambda p: p.baseline and timed_quietly(p, allow_loaded))
        for point in points:
            if point.baseline:
                continue
            if not timed_quietly(point, allow_loaded):
                found = Speedup(None, "n/a", note=LOADED_REASON, against=against)
            elif not _usable(point, key):
                found = Speedup(None, "n/a", note=f"no {metric.label} (withheld or not finite)",
                                against=against)
            elif not baseline:
                found = Speedup(None, "n/a", note=f"no series of the {against} has two points "
                                                  f"with a {metric.label}", against=against)
            else:
                found = bootstrap_speedup(baseline, _sample(point, key), against=against,
                                          resamples=resamples)
            setattr(point, f"speedup_{key}", found)
    return [{"label": p.label, "reason": LOADED_REASON}
            for p in points if not timed_quietly(p, allow_loaded)]


def strongest_pt_curves(points: list[ParetoPoint], key: str,
                        allow_loaded: bool = False) -> dict[str, Curve]:
    """The curves of the strongest PT's candidates for the error ``key``, of points timed
    quietly unless ``allow_loaded`` (the envelope of the JSON and of the plots)."""
    return sample_curves(_baseline_samples(
        points, key, lambda p: p.named_baseline == STRONGEST_PT and timed_quietly(p, allow_loaded)))


def baselines(points: list[ParetoPoint], chosen: str,
              allow_loaded: bool = False) -> dict[str, Any]:
    """The baselines of the JSON: which one the speed-ups are against, what the paper's PT
    and the strongest PT are, and per error the strongest PT's envelope (the time
    intervals over which each candidate's curve is lowest; of points timed quietly
    unless ``allow_loaded``)."""
    def envelope(key: str) -> list[dict[str, Any]]:
        return [asdict(piece)
                for piece in envelope_pieces(strongest_pt_curves(points, key, allow_loaded))]

    paper = PTParams()
    return {"speedups_against": baseline_label(chosen), "baseline": chosen,
            PAPER_PT: {"label": BASELINE_LABELS[PAPER_PT],
                       "definition": f"{BASELINE} with its defaults: Russian roulette "
                                     f"'{paper.rr_mode}', survival {paper.rr_survival} from "
                                     f"depth {paper.rr_depth} (the NIRC paper's)"},
            STRONGEST_PT: {"label": BASELINE_LABELS[STRONGEST_PT],
                           "candidates": list(dict.fromkeys(
                               p.series for p in points if p.named_baseline == STRONGEST_PT)),
                           "candidate_params": STRONGEST_PT_PARAMS,
                           "definition": ENVELOPE_DEFINITION,
                           "envelope": {m.field: envelope(m.field) for m in PARETO_METRICS}}}


def _usable(point: ParetoPoint, key: str) -> bool:
    """The point has the error ``key`` and every seed's value of it, all finite."""
    values = [getattr(point, key), *getattr(point, f"{key}_per_seed")]
    return all(v is not None and np.isfinite(v) for v in values)


def _sample(point: ParetoPoint, key: str) -> Sample:
    return Sample(errors=getattr(point, f"{key}_per_seed"), seconds=point.timing_samples)


def write_outputs(result: ParetoResult, out_dir: Path) -> dict[str, str]:
    """pareto.json and one plot per metric (pareto_<field>.png) in ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    files = {}
    for metric in PARETO_METRICS:
        path = out_dir / f"pareto_{metric.field}.png"
        envelope = envelope_line(strongest_pt_curves(result.points, metric.field,
                                                     result.spec.allow_loaded))
        plot_pareto([p.model_dump() for p in result.points], metric.field, metric.label, path,
                    f"{metric.label} against time per frame on {result.spec.scene} "
                    f"({result.spec.resolution}x{result.spec.resolution}, {result.device})",
                    envelope=envelope)
        files[f"pareto_{metric.field}"] = str(path)
    files["json"] = str(out_dir / "pareto.json")
    Path(files["json"]).write_text(json.dumps({**result.to_json(), "files": files}, indent=2,
                                              default=str))
    return files
