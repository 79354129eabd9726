"""The method comparison of the NIRC paper's Fig. 7, at equal spp and at equal time.

The runs are the registry's (each method's ``comparison``, ordered by rank):
PT 1 spp, PT 2 spp, NRC (biased), NIRC biased, NIRC unbiased, the grid cache — each run
through the executor (so every row is a stored run against the same reference)
and reported with the listed metrics of metrics.registry (MRSE with its CI, rBias²,
rVar, FLIP, PSNR, ...) and milliseconds per frame (total, and the render stage
alone; the caches' totals include their online training).

Equal time on this device: the papers' GPU ordering (a neural sample costs a few
% of a path) need not hold on a CPU, so we do not assume it. For NIRC biased we
calibrate N_c (jobs.protocol.calibration, a job time budget; a 'knob' run): the largest
of its knob's candidates 1, 2, 4, ..., 32 whose frame time fits the PT 2 spp
budget (the 'budget' run; none fitting is reported as such); and for every
'matched' cached method PT gets the largest spp that fits that method's frame
time ("PT at equal time"). Each calibration is stored with its run.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pydantic import BaseModel, Field

from jobs.protocol.calibration import caveats
from jobs.protocol.executor import RunSummary, execute
from jobs.protocol.job import RenderJob
from jobs.protocol.results import ReportRow, Skipped
from jobs.protocol.spec import ReferenceSpec, RenderSpec, TimeBudget
from jobs.record.config import Settings
from jobs.record.store import Store
from renderers.methods import BASELINE, METHODS, NotApplicable


class Report(BaseModel):
    """The comparison: rows at equal spp and at equal time (each a stored run's public
    result, jobs.protocol.results), the N_c calibration, the methods the scene rules out."""

    scene: str
    device: str
    equal_spp: list[ReportRow] = Field(default_factory=list)
    equal_time: list[ReportRow] = Field(default_factory=list)
    calibration: dict[str, Any] = Field(default_factory=dict)
    skipped: list[Skipped] = Field(default_factory=list)


def _row(label: str, summary: RunSummary, note: str = "") -> ReportRow:
    return ReportRow.model_validate({**summary.result.model_dump(), "label": label,
                                     "note": note})


def comparison_report(
    scene: str, store: Store, settings: Settings, *, resolution: int = 64, frames: int = 16,
    seeds: int = 2, pretrain_frames: int = 100, max_depth: int = -1, ref_spp: int = 4096,
    progress: Callable[[str, int, int], None] | None = None,
) -> Report:
    """Run the Fig. 7 comparison on ``scene`` (see the module docstring)."""
    base = RenderSpec(scene=scene, resolution=resolution, frames=frames, seeds=seeds,
                      reference=ReferenceSpec(spp=ref_spp))

    def run(label: str, method: str, params: dict[str, Any], spp: int = 1,
            budget: TimeBudget | None = None) -> RunSummary | None:
        spec = base.model_copy(update={"method": method, "params": params, "spp": spp,
                                       "time_budget": budget})
        step = (lambda stage, done, total: progress(f"{label}: {stage}", done, total)) \
            if progress else None
        try:
            return execute(RenderJob.parse(spec), store, settings, progress=step)
        except NotApplicable as err:   # the method's applies_to rules the scene out
            report.skipped.append(Skipped(method=method, label=label, reason=str(err)))
            return None

    def shared(method: str) -> dict[str, Any]:
        return METHODS[method].shared_params(max_depth, pretrain_frames)

    entries = sorted(((name, entry) for name, method in METHODS.items()
                      for entry in method.comparison), key=lambda item: item[1].rank)
    report = Report(scene=scene, device="")
    summaries: dict[str, RunSummary] = {}
    for name, entry in entries:
        if entry.role != "knob":
            summary = run(entry.label, name, {**shared(name), **entry.params}, spp=entry.spp)
            if summary is not None:
                summaries[entry.label] = summary
    report.device = next(iter(summaries.values())).device["device_key"]
    report.equal_spp = [_row(entry.row, summaries[entry.label]) for _, entry in entries
                        if entry.label in summaries]

    # ---- Equal time: a method's knob calibrated to the budget run's frame time ----
    budget = next(entry for _, entry in entries if entry.role == "budget")
    baseline = METHODS[BASELINE].label or BASELINE
    for name, entry in entries:
        if entry.role != "knob":
            continue
        knob = METHODS[name].knob
        summary = run(entry.label, name, {**shared(name), **entry.params},
                      budget=TimeBudget(pt_spp=budget.spp,
                                        candidates=list(knob.candidates if knob else ())))
        if summary is None:
            continue
        calibration = summary.metrics["calibration"]
        report.calibration = calibration
        if not report.equal_time:
            report.equal_time.append(_row(f"{budget.row} (budget)", summaries[budget.label]))
        notes = [*([] if calibration["fits"] else [entry.unfit]), *caveats(calibration)]
        report.equal_time.append(_row(entry.row.format(chosen=calibration["chosen"]), summary,
                                      "; ".join(notes)))

    # ---- Equal time: the baseline with the spp that fits each matched method's time ----
    for _name, entry in entries:
        if entry.role != "matched" or entry.label not in summaries:
            continue
        summary = summaries[entry.label]
        pt_eq = run(f"{baseline} (= {entry.label} time)", BASELINE, {"max_depth": max_depth},
                    budget=TimeBudget(ms=1e3 * summary.timings["seconds_per_frame"]))
        assert pt_eq is not None    # the baseline renders every scene
        report.equal_time += [_row(entry.label, summary),
                              _row(f"{baseline} {pt_eq.spec.spp} spp (= {entry.label} time)",
                                   pt_eq, "; ".join(caveats(pt_eq.metrics["calibration"])))]
    return report
