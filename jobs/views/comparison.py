"""Stored runs side by side: what differs between them and how their metrics moved.

One comparison for ``GET /api/v1/compare`` and ``nirc-bench runs compare``. The first
run is the baseline; every other run gets, per listed metric, its value, the change
from the baseline and, when both runs have at least :data:`MIN_SEEDS_FOR_INTERVAL`
seeds, the Welch 95 % interval of the difference of the seed means
(:func:`metrics.statistics.welch_interval`) over the metric's values per seed: MRSE's,
FLIP's and PSNR's own, rBias²'s and rVar's stored seed values (the caches' own rBias²,
or the delete-one-seed jackknife values of a pooled estimate, whose means are the run's
values: metrics.bias_intervals). A change "differs" when that interval excludes 0. Each
run also shows its time per frame, its efficiency 1 / (MRSE x time) with an interval,
its load flags and its verdicts. Runs scored under different metric versions are
refused: their numbers measure different things.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel, Field

from jobs.protocol.results import RunResult
from jobs.views.animation_comparison import AnimationDelta, compare_animations
from metrics.registry import LISTED, Metric, below_noise_floor
from metrics.statistics import welch_interval

if TYPE_CHECKING:
    from collections.abc import Sequence

#: Fewer seeds than this per run give no interval (a t interval on 1 or 2 degrees of
#: freedom spans most of the axis).
MIN_SEEDS_FOR_INTERVAL = 3

#: What a run is besides its method parameters, as the comparison lists differences.
SETTINGS = ("scene", "scene_fingerprint", "method", "resolution", "spp", "frames", "seeds",
            "device_key", "estimator_version")


class ComparisonError(ValueError):
    """Runs that cannot be compared (scored under different metric definitions)."""


class MetricDelta(BaseModel):
    """One metric of a run against the baseline's."""

    metric: str = Field(description="the metric's registry name")
    key: str = Field(description="its stored key (metrics.registry)")
    label: str
    direction: str = Field(description="which way is better: lower or higher")
    baseline: float | None
    value: float | None
    delta: float | None = Field(description="value - baseline")
    ratio: float | None = Field(description="value / baseline (null when the baseline is 0 "
                                            "or either is below the noise floor)")
    delta_ci95: list[float] | None = Field(
        description="Welch 95 % interval of the difference of the seed means (null: see "
                    "interval_note)")
    interval_note: str = Field(description="how the interval was made, or why there is none")
    differs: bool | None = Field(
        None, description="whether the interval of the change excludes 0 (null: no interval)")


class RunStanding(BaseModel):
    """What a compared run is besides its listed metrics: speed, efficiency, flags, verdicts."""

    run: int
    ms_per_frame: float | None = Field(description="median milliseconds per frame")
    efficiency: float | None = Field(description="1 / (MRSE x seconds per frame) [1/s]")
    efficiency_ci95: list[float] | None = Field(
        description="1 / (MRSE's 95 % interval x seconds per frame): the frame time taken "
                    "as exact (null without an MRSE interval)")
    timing_flags: list[str] = Field(description="why its timing may not be trusted (loaded)")
    verdict: str | None = Field(description="its quality verdict (e.g. undertrained-cache)")
    bias_verdict: str | None = Field(description="'biased' or 'within noise' (rBias²'s "
                                                 "95 % interval)")
    rbias2_basis: str | None = Field(description="'per cache' or 'pooled'")


class RunDelta(BaseModel):
    """A run's metrics against the baseline's (the first run compared)."""

    run: int
    baseline: int
    metrics: list[MetricDelta]


class RunComparison(BaseModel):
    """Runs side by side, what differs between them, and how their metrics moved."""

    runs: list[RunResult]
    same_device: bool
    same_reference_scene: bool
    metric_version: int = Field(description="every compared run was scored under it")
    estimator_versions: dict[str, list[int]] = Field(
        description="method -> the estimator versions among the runs; two versions of one "
                    "method are different estimators, not repeats")
    differences: dict[str, list[Any]] = Field(
        default_factory=dict,
        description="every setting and method parameter whose value is not the same in "
                    "all runs -> its value in each run, in order ('params.NAME' for a "
                    "parameter; null where a run has none)")
    deltas: list[RunDelta] = Field(
        default_factory=list, description="each later run's metrics against the first's")
    standings: list[RunStanding] = Field(
        default_factory=list, description="each run's speed, efficiency, load flags and "
                                          "verdicts, in order")
    animation: list[AnimationDelta] = Field(
        default_factory=list, description="where a run is animated: each later run's "
                                          "recovery after each change and steady error per "
                                          "segment against the first's, or why they are not "
                                          "comparable (jobs/views/animation_comparison.py)")
    note: str


def _seed_values(run: Any, metric: Metric) -> list[float]:
    """``metric``'s values per seed whose mean is the run's value: each seed's own, or
    the stored ``<key>_seed_values`` (rBias², rVar)."""
    if metric.seed_key:
        values: Sequence[Any] = [s.metrics.get(metric.seed_key) for s in run.seed_results]
    else:
        values = run.metrics.get(f"{metric.key}_seed_values") or [] if metric.interval else []
    return [float(v) for v in values if v is not None and np.isfinite(v)]


def standing(row: RunResult) -> RunStanding:
    """``row``'s speed, efficiency with its interval, load flags and verdicts."""
    seconds, mrse, ci = row.seconds_per_frame, row.mrse, row.mrse_ci95
    usable = seconds is not None and seconds > 0 and mrse is not None and mrse > 0
    return RunStanding(
        run=row.id, ms_per_frame=None if seconds is None else 1e3 * seconds,
        efficiency=1.0 / (mrse * seconds) if usable else None,
        efficiency_ci95=([1.0 / (ci[1] * seconds), 1.0 / (ci[0] * seconds)]
                         if usable and ci and ci[0] > 0 else None),
        timing_flags=row.timing_flags, verdict=row.verdict, bias_verdict=row.bias_verdict,
        rbias2_basis=row.rbias2_basis)


def metric_delta(metric: Metric, baseline: Any, run: Any) -> MetricDelta:
    """``metric`` of the stored ``run`` against ``baseline`` (both loaded with their seeds)."""
    base, value = baseline.metrics.get(metric.key), run.metrics.get(metric.key)
    delta = None if base is None or value is None else value - base
    ratio = (None if delta is None or base == 0 or below_noise_floor(metric.key, base)
             or below_noise_floor(metric.key, value) else value / base)
    ci, note = None, "no interval: the metric has no value per seed"
    if metric.seed_key or metric.interval:
        a, b = _seed_values(run, metric), _seed_values(baseline, metric)
        if min(len(a), len(b)) < MIN_SEEDS_FOR_INTERVAL:
            note = (f"no interval: fewer than {MIN_SEEDS_FOR_INTERVAL} seeds with a value "
                    f"({len(b)} and {len(a)})")
        else:
            low, high = welch_interval(a, b, 0.95)
            ci = [float(low), float(high)] if np.isfinite([low, high]).all() else None
            note = ("Welch 95 % interval of the difference of the seed means" if ci else
                    "no interval: the seeds' values do not vary")
    return MetricDelta(metric=metric.name, key=metric.key, label=metric.label, direction=metric.direction,
                       baseline=base, value=value, delta=delta, ratio=ratio,
                       delta_ci95=ci, interval_note=note,
                       differs=None if ci is None else not ci[0] <= 0.0 <= ci[1])


def differences(rows: list[RunResult]) -> dict[str, list[Any]]:
    """The settings and parameters whose values differ between ``rows``."""
    columns = {name: [getattr(r, name) for r in rows] for name in SETTINGS}
    names = dict.fromkeys(name for r in rows for name in r.params)
    columns.update({f"params.{name}": [r.params.get(name) for r in rows] for name in names})
    return {name: values for name, values in columns.items()
            if any(v != values[0] for v in values[1:])}


def compare_runs(runs: list[Any]) -> RunComparison:
    """Compare the stored ``runs`` (loaded as ``Store.get_run`` loads them; the first is
    the baseline). ComparisonError when their metric versions differ."""
    rows = [RunResult.of(run) for run in runs]
    metric_versions = sorted({r.metric_version for r in rows})
    if len(metric_versions) > 1:
        listed = ", ".join(f"run {r.id}: v{r.metric_version}" for r in rows)
        raise ComparisonError("these runs were scored under different metric definitions "
                              f"({listed}); their numbers are not comparable: compare runs "
                              "of one metric version (re-run the old ones)")
    estimators: dict[str, set[int]] = {}
    for r in rows:
        estimators.setdefault(r.method, set()).add(r.estimator_version)
    same_device = len({r.device_key for r in rows}) == 1
    same_scene = len({(r.scene_fingerprint, tuple(r.resolution)) for r in rows}) == 1
    loaded = [r.id for r in rows if r.timing_flags]
    notes = ["different devices: compare errors only, not timings" if not same_device else
             f"timings not comparable: run(s) {', '.join(map(str, loaded))} timed on a loaded "
             "machine" if loaded else "timings comparable (same device, none loaded)"]
    notes += [f"{method} runs of estimator versions {', '.join(map(str, sorted(v)))} are "
              "different estimators, not repeats of one" for method, v in estimators.items()
              if len(v) > 1]
    found = differences(rows)
    references = [None if run.reference is None else
                  f"{run.reference.id} ({run.reference.integrator}, {run.reference.spp} spp, "
                  f"max_depth {run.reference.max_depth})" for run in runs]
    if any(ref != references[0] for ref in references[1:]):
        found["reference"] = references
        notes.append("different references: errors are measured against different images")
    deltas = [RunDelta(run=run.id, baseline=runs[0].id,
                       metrics=[metric_delta(m, runs[0], run) for m in LISTED])
              for run in runs[1:]]
    animation = [delta for run in runs[1:]
                 if (delta := compare_animations(runs[0].id, runs[0].metrics, run.id,
                                                 run.metrics))]
    notes += [delta.note for delta in animation if not delta.comparable]
    return RunComparison(runs=rows, same_device=same_device, same_reference_scene=same_scene,
                         metric_version=metric_versions[0],
                         estimator_versions={m: sorted(v) for m, v in estimators.items()},
                         differences=found, deltas=deltas, animation=animation,
                         standings=[standing(r) for r in rows], note="; ".join(notes))
