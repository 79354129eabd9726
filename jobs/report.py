"""The method comparison of the NIRC paper's Fig. 7, at equal spp and at equal time.

Rows: PT 1 spp, PT 2 spp, NRC (biased), NIRC biased, NIRC unbiased — each run
through the executor (so every row is a stored run against the same reference)
and reported with the listed metrics of metrics.registry (MRSE with its CI, rBias²,
rVar, FLIP, PSNR, ...) and milliseconds per frame (total, and the render stage
alone; the caches' totals include their online training).

Equal time on this device: the papers' GPU ordering (a neural sample costs a few
% of a path) need not hold on a CPU, so we do not assume it. For NIRC biased we
calibrate N_c (jobs.calibration, a job time budget): the largest of 1, 2, 4,
..., 32 whose frame time fits the PT 2 spp budget (none fitting is reported as
such); and for every cached method PT gets the largest spp that fits that
method's frame time ("PT at equal time"). Each calibration is stored with its run.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, make_dataclass
from typing import Any

from jobs.config import Settings
from jobs.executor import RunSummary, execute
from jobs.spec import ReferenceSpec, RenderSpec, TimeBudget
from jobs.store import Store
from metrics.registry import row_values

NC_CANDIDATES = (1, 2, 4, 8, 16, 32)


def _report_row_fields() -> list[tuple[str, Any, Any]]:
    """ReportRow's fields: the run, then one per listed metric of metrics.registry
    (``mrse``, ``mrse_ci95``, ``flip``, ``rbias2``, ``rvar``, ``psnr``), then the timings."""
    metric_fields = [(name, Any, None) for name in row_values({})]
    return [("label", str), ("run_id", int), ("method", str), ("params", dict[str, Any]),
            ("spp", int), ("ms_frame", float), ("ms_render", float), ("note", str, ""),
            *metric_fields]


#: One row of the comparison; its metric fields are generated from the registry.
ReportRow = make_dataclass("ReportRow", _report_row_fields())


@dataclass
class Report:
    scene: str
    device: str
    equal_spp: list[Any] = field(default_factory=list)    # ReportRow
    equal_time: list[Any] = field(default_factory=list)   # ReportRow
    calibration: dict[str, Any] = field(default_factory=dict)


def _row(label: str, summary: RunSummary, note: str = "") -> Any:
    m, t = summary.metrics, summary.timings
    render = t["stages"].get("render", {}).get("median_s", t["seconds_per_frame"])
    return ReportRow(label=label, run_id=summary.run_id, method=summary.spec.method,
                     params=summary.spec.params, spp=summary.spec.spp, **row_values(m),
                     ms_frame=1e3 * t["seconds_per_frame"], ms_render=1e3 * render, note=note)


def comparison_report(
    scene: str, store: Store, settings: Settings, *, resolution: int = 64, frames: int = 16,
    seeds: int = 2, pretrain_frames: int = 100, max_depth: int = -1, ref_spp: int = 4096,
    progress: Callable[[str, int, int], None] | None = None,
) -> Report:
    """Run the Fig. 7 comparison on ``scene`` (see the module docstring)."""
    base = RenderSpec(scene=scene, resolution=resolution, frames=frames, seeds=seeds,
                      reference=ReferenceSpec(spp=ref_spp))
    cache_params = {"max_depth": max_depth, "pretrain_frames": pretrain_frames}

    def run(label: str, method: str, params: dict[str, Any], spp: int = 1,
            budget: TimeBudget | None = None) -> RunSummary:
        spec = base.model_copy(update={"method": method, "params": params, "spp": spp,
                                       "time_budget": budget})
        step = (lambda stage, done, total: progress(f"{label}: {stage}", done, total)) \
            if progress else None
        return execute(spec, store, settings, progress=step)

    pt1 = run("PT 1 spp", "pt", {"max_depth": max_depth})
    pt2 = run("PT 2 spp", "pt", {"max_depth": max_depth}, spp=2)
    nrc = run("NRC", "nrc", cache_params)
    nirc_b = run("NIRC biased", "nirc", {**cache_params, "estimator": "biased", "nc": [4]})
    nirc_u = run("NIRC unbiased", "nirc", {**cache_params, "estimator": "unbiased",
                                           "nc": [3, 1, 1]})
    report = Report(scene=scene, device=pt1.device["device_key"])
    report.equal_spp = [_row("PT 1 spp", pt1), _row("PT 2 spp", pt2), _row("NRC biased", nrc),
                        _row("NIRC biased (N_c 4)", nirc_b),
                        _row("NIRC unbiased (N_c 3,1,1)", nirc_u)]

    # ---- Equal time: N_c of NIRC biased calibrated to the PT 2 spp frame time ----
    nirc_eq = run("NIRC biased (equal time)", "nirc",
                  {**cache_params, "estimator": "biased"},
                  budget=TimeBudget(pt_spp=2, candidates=list(NC_CANDIDATES)))
    calibration = nirc_eq.metrics["calibration"]
    report.calibration = calibration
    chosen = calibration["chosen"]
    report.equal_time = [
        _row("PT 2 spp (budget)", pt2),
        _row(f"NIRC biased (N_c {chosen})", nirc_eq,
             "" if calibration["fits"] else "over budget even at N_c = 1"),
    ]

    # ---- Equal time: PT with the spp that fits each cached method's frame time ----
    for label, summary in (("NRC", nrc), ("NIRC unbiased", nirc_u)):
        pt_eq = run(f"PT (= {label} time)", "pt", {"max_depth": max_depth},
                    budget=TimeBudget(ms=1e3 * summary.timings["seconds_per_frame"]))
        report.equal_time += [_row(label, summary),
                              _row(f"PT {pt_eq.spec.spp} spp (= {label} time)", pt_eq)]
    return report
