"""Chart specs for the dashboard: Vega-Lite dicts (jobs/views/charts.py) of stored
results, each chart holding only comparable runs (jobs/views/chart_groups.py)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, status

from jobs.ci.history import MAX_HISTORY_RUNS, build_history
from jobs.protocol.results import RunResult, RunResultDetail
from jobs.protocol.versions import current_estimator_versions
from jobs.views.animation_chart import animated_view, frame_error_chart
from jobs.views.animation_comparison import compare_animations
from jobs.views.chart_groups import Setting, config_label, history_series_label, split_groups
from jobs.views.charts import convergence_chart, error_time_chart, history_chart, sweep_chart
from metrics import METRIC_VERSION
from metrics.registry import METRICS
from service.api.deps import RowId, StoreDep

router = APIRouter(prefix="/api/v1/charts", tags=["charts"])

Name = Annotated[str, Query(min_length=1, max_length=500, pattern=r"^[^\x00]*$")]
#: The errors drawn against time, by result field (as `nirc-bench pareto` draws them).
TIME_METRICS = ("mrse", "flip")


def _listed() -> list[dict[str, Any]]:
    return [m.to_json() for m in METRICS if m.field]


def _animated(row: dict[str, Any], metrics: dict[str, Any]) -> dict[str, Any]:
    """A run as jobs.views.animation_chart reads it."""
    return {"id": row["id"], "method": row["method"], "label": config_label(row),
            "animation": metrics.get("animation")}


@router.get("/scene")
def scene_charts(store: StoreDep, scene: Name, include_old: bool = False) -> dict[str, Any]:
    """Error-vs-time charts of a scene's runs: per group of comparable runs (scene,
    resolution, frames, protocol, device, versions) one chart per error, each method's
    curve over its knobs (spp, N_c, eps) in it, with the group's Pareto front."""
    versions = {} if include_old else {"current": current_estimator_versions(),
                                       "metric_version": METRIC_VERSION}
    stored = store.list_runs(scene, None, None, limit=1000, **versions)
    runs = [RunResult.of(run).model_dump(mode="json") for run in stored]
    animations = {run.id: run.metrics or {} for run in stored}
    metrics = [m for m in _listed() if m["field"] in TIME_METRICS]
    groups = []
    for group, members in split_groups(runs).items():
        charts = [chart for m in metrics if (chart := error_time_chart(group, members, m))]
        # One animated chart per animation of the group: others change at other frames.
        by_digest: dict[str, list[dict[str, Any]]] = {}
        for r in members:
            animated = _animated(r, animations[r["id"]])
            if animated["animation"]:
                by_digest.setdefault(animated["animation"]["digest"], []).append(animated)
        groups.append({"title": group.title, "runs": [r["id"] for r in members],
                       "charts": charts,
                       "animations": [animated_view(same) for same in by_digest.values()]})
    return {"scene": scene, "groups": groups}


@router.get("/history")
def history_charts(store: StoreDep, scene: Name, method: Name) -> dict[str, Any]:
    """Per listed metric its history over commits (GET /api/v1/ci/history), one chart per
    setting (scene, resolution, frames, protocol, device: jobs/views/chart_groups.py),
    one line per run label and spp, never pooled; ``below_noise_floor`` counts the
    medians at or below 0 a metric's log axis cannot draw, of its ``medians``."""
    runs = store.list_history_runs(scene, method, limit=MAX_HISTORY_RUNS)
    devices = sorted({run.device_key for run in runs})
    answer = []
    for metric in METRICS:
        if not metric.field:
            continue
        settings: dict[Setting, list[tuple[str, list[dict[str, Any]]]]] = {}
        for device in devices:
            history = build_history(runs, metric, scene=scene, method=method, device=device)
            for series in history.model_dump(mode="json")["series"]:
                width, height = series["resolution"]
                setting = Setting(scene, width, height, series["frames"], series["protocol"],
                                  device)
                settings.setdefault(setting, []).append(
                    (history_series_label(series["label"], series["spp"]), series["points"]))
        ordered = sorted(settings.items(), key=lambda item: item[0])
        charts = [{"setting": setting.title, "spec": spec} for setting, series in ordered
                  if (spec := history_chart(metric.to_json(), setting.title, method,
                                            sorted(series, key=lambda s: s[0])))]
        medians = [point["median"] for _, series in ordered for _, points in series
                   for point in points if point["median"] is not None]
        answer.append({"metric": metric.name, "label": metric.label, "charts": charts,
                       # Medians a log axis cannot draw (a noise-corrected value <= 0 is
                       # below the noise floor): all of them when no chart is drawn.
                       "below_noise_floor": sum(m <= 0 for m in medians)
                       if metric.log_axis else 0, "medians": len(medians),
                       "steps": [{**point, "setting": setting.title, "config": label}
                                 for setting, series in ordered
                                 for label, points in series for point in points
                                 if point["step"]]})
    return {"scene": scene, "method": method, "metrics": answer}


@router.get("/runs/{run_id}")
def run_charts(run_id: RowId, store: StoreDep) -> dict[str, Any]:
    """A run's convergence over frames (null, with why, for a run of one frame)."""
    run = store.get_run(run_id)
    if run is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no run {run_id}")
    detail = RunResultDetail.of(run).model_dump(mode="json")
    chart = convergence_chart(detail)
    return {"run": run_id, "convergence": chart,
            "note": None if chart else "no convergence curve: the run has one frame "
                                       "(or stored none)",
            "animation": animated_view([_animated(detail, detail["metrics"])])}


@router.get("/compare/{baseline_id}/{run_id}")
def comparison_charts(baseline_id: RowId, run_id: RowId, store: StoreDep) -> dict[str, Any]:
    """Two animated runs' error per frame on one chart, the baseline's changes as rules
    (GET /api/v1/compare lists their recovery, steady errors and flicker); null, with
    why, unless both are animated and comparable frame by frame
    (jobs/views/animation_comparison.py)."""
    runs = []
    for found_id in (baseline_id, run_id):
        run = store.get_run(found_id)
        if run is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"no run {found_id}")
        runs.append(RunResultDetail.of(run).model_dump(mode="json"))
    delta = compare_animations(baseline_id, runs[0]["metrics"], run_id, runs[1]["metrics"])
    comparable = delta is not None and delta.comparable
    return {"runs": [baseline_id, run_id],
            "animation": frame_error_chart([_animated(run, run["metrics"]) for run in runs])
            if comparable else None,
            "note": None if comparable else delta.note if delta else "neither run is animated"}


@router.get("/sweeps/{sweep_id}")
def sweep_charts(sweep_id: RowId, store: StoreDep) -> dict[str, Any]:
    """A sweep's curves, one chart per metric the registry plots for sweeps, and what it
    swept (``title``): the adaptive equal-bias sweep over eps, or a sweep over one
    parameter, drawn against its values."""
    sweep = store.get_sweep(sweep_id)
    if sweep is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no sweep {sweep_id}")
    rows = (sweep.result or {}).get("rows") or []
    parameter = (sweep.result or {}).get("parameter") if sweep.kind == "parameter" else None
    charts = [sweep_chart(sweep_id, rows, m.to_json(), parameter)
              for m in METRICS if m.sweep_plot]
    title = f"Sweep over {parameter}" if parameter else "Adaptive equal-bias sweep"
    return {"sweep": sweep_id, "title": title, "charts": [chart for chart in charts if chart]}
