"""The method comparison of the NIRC paper's Fig. 7, at equal spp and at equal time.

The runs are the registry's (each method's ``comparison``, ordered by rank):
PT 1 spp, PT 2 spp (the paper's PT: ``pt``'s fixed roulette, labelled so), NRC
(biased), NIRC biased, NIRC unbiased, the grid cache — each run
through the executor (so every row is a stored run against the same reference)
and reported with the listed metrics of metrics.registry (MRSE with its CI, rBias²,
rVar, FLIP, PSNR, ...) and milliseconds per frame (total, and the render stage
alone; the caches' totals include their online training).

Equal time on this device: the papers' GPU ordering (a neural sample costs a few
% of a path) need not hold on a CPU, so we do not assume it. For NIRC biased we
calibrate N_c (jobs.protocol.calibration, a job time budget; a 'knob' run): the largest
of its knob's candidates 1, 2, 4, ..., 32 whose frame time fits the PT 2 spp
budget (the 'budget' run; none fitting is reported as such); and for every
'matched' cached method two PT rows at its frame time: the paper's PT with the
largest spp that fits it, and the strongest PT there: each of its candidates
(jobs.pareto.plan: the PT core's methods with throughput roulette) calibrated the
same way, the one of lowest MRSE shown (the lower envelope at that time, on the spp
grid; docs/pareto.md). Each calibration is stored with its run.

Bounding the PT calibrations (a quick run): ``max_pt_spp`` keeps the PT candidates at
most that spp (a matched time PT would spend on more is reported ``capped``: its PT
rows then have less than equal time), ``strongest`` names the strongest PT's candidates
calibrated (default: all; none: no strongest-PT rows); the report states both in
``bounds``.

Leaving rows out (a quick run whose claims need fewer): ``runs`` names the comparison
runs rendered by their registry labels (default: all; the budget run, PT 2 spp, is always
needed), ``pt_at`` the matched runs at whose frame time the PT rows are calibrated
(default: every matched run rendered); both are stated in ``bounds`` too.

Loaded timings (renderers.load): a calibration leaves out probes taken on a loaded
machine (jobs.protocol.calibration), and a matched method whose own run was timed on a
loaded machine gives no budget: its equal-time rows are left out, listed with the reason
in ``left_out``, unless ``allow_loaded``. Every row's ``timing_flags`` say whether its
run was timed loaded.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from pydantic import BaseModel, Field

from jobs.pareto.plan import (
    BASELINE_LABELS,
    PAPER_PT,
    STRONGEST_PT,
    STRONGEST_PT_PARAMS,
    pt_core_methods,
)
from jobs.protocol.calibration import LoadedMachineError, caveats
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
    left_out: list[Skipped] = Field(
        default_factory=list, description="equal-time rows left out for a loaded machine, "
                                          "with the reason")
    bounds: dict[str, Any] = Field(
        default_factory=dict, description="the PT calibrations' bounds: max_pt_spp (None: "
                                          "the knob's candidates), the strongest PT's "
                                          "candidates calibrated; the comparison runs "
                                          "rendered (runs) and the matched ones with PT "
                                          "rows at their time (pt_at)")


def _row(label: str, summary: RunSummary, note: str = "") -> ReportRow:
    return ReportRow.model_validate({**summary.result.model_dump(), "label": label,
                                     "note": note})


def comparison_report(
    scene: str, store: Store, settings: Settings, *, resolution: int = 64, frames: int = 16,
    seeds: int = 2, pretrain_frames: int = 100, max_depth: int = -1, ref_spp: int = 4096,
    progress: Callable[[str, int, int], None] | None = None, allow_loaded: bool = False,
    max_pt_spp: int | None = None, strongest: tuple[str, ...] | None = None,
    runs: tuple[str, ...] | None = None, pt_at: tuple[str, ...] | None = None,
) -> Report:
    """Run the Fig. 7 comparison on ``scene`` (see the module docstring); ``allow_loaded``:
    use timings taken on a loaded machine for the equal-time budgets; ``max_pt_spp`` and
    ``strongest``: the PT calibrations' bounds; ``runs`` and ``pt_at``: the rows left
    out (module docstring)."""
    core = pt_core_methods()
    chosen = list(core if strongest is None else strongest)
    if set(chosen) - set(core):
        raise ValueError(f"strongest: give any of {', '.join(core)} (none: no strongest-PT "
                         "rows)")
    if max_pt_spp is not None and max_pt_spp < 1:
        raise ValueError("max_pt_spp must be at least 1")
    entries = sorted(((name, entry) for name, method in METHODS.items()
                      for entry in method.comparison), key=lambda item: item[1].rank)
    labels = [entry.label for _name, entry in entries]
    budget_name, budget = next(item for item in entries if item[1].role == "budget")
    rendered = labels if runs is None else [label for label in labels if label in runs]
    if runs is not None and (set(runs) - set(labels) or budget.label not in runs):
        raise ValueError(f"runs: give labels of {', '.join(labels)}, {budget.label} among "
                         "them (the equal-time budget)")
    matched = [entry.label for _name, entry in entries
               if entry.role == "matched" and entry.label in rendered]
    if pt_at is not None and set(pt_at) - set(matched):
        raise ValueError(f"pt_at: give matched runs rendered: {', '.join(matched)}")
    entries = [(name, entry) for name, entry in entries if entry.label in rendered]
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
        except LoadedMachineError as err:
            report.left_out.append(Skipped(method=method, label=label, reason=str(err)))
            return None

    def shared(method: str) -> dict[str, Any]:
        return METHODS[method].shared_params(max_depth, pretrain_frames)

    report = Report(scene=scene, device="", bounds={
        "max_pt_spp": max_pt_spp, "strongest": chosen, "runs": rendered,
        "pt_at": matched if pt_at is None else [m for m in matched if m in pt_at]})
    summaries: dict[str, RunSummary] = {}
    for name, entry in entries:
        if entry.role != "knob":
            summary = run(entry.label, name, {**shared(name), **entry.params}, spp=entry.spp)
            if summary is not None:
                summaries[entry.label] = summary
    report.device = next(iter(summaries.values())).device["device_key"]
    baseline = METHODS[BASELINE].label or BASELINE
    paper = BASELINE_LABELS[PAPER_PT]

    def row_label(name: str, row: str) -> str:
        """A row's label, the baseline's named as the paper's PT."""
        return f"{paper}{row[len(baseline):]}" if name == BASELINE and \
            row.startswith(baseline) else row

    report.equal_spp = [_row(row_label(name, entry.row), summaries[entry.label])
                        for name, entry in entries if entry.label in summaries]

    # ---- Equal time: a method's knob calibrated to the budget run's frame time ----
    for name, entry in entries:
        if entry.role != "knob":
            continue
        knob = METHODS[name].knob
        summary = run(entry.label, name, {**shared(name), **entry.params},
                      budget=TimeBudget(pt_spp=budget.spp, allow_loaded=allow_loaded,
                                        candidates=list(knob.candidates if knob else ())))
        if summary is None:
            continue
        calibration = summary.metrics["calibration"]
        report.calibration = calibration
        if not report.equal_time:
            report.equal_time.append(_row(f"{row_label(budget_name, budget.row)} (budget)",
                                          summaries[budget.label]))
        notes = [*([] if calibration["fits"] else [entry.unfit]), *caveats(calibration)]
        report.equal_time.append(_row(entry.row.format(chosen=calibration["chosen"]), summary,
                                      "; ".join(notes)))

    # ---- Equal time: the paper's and the strongest PT at each matched method's time ----
    strongest_label = BASELINE_LABELS[STRONGEST_PT]

    def pt_budget(name: str, ms: float) -> TimeBudget:
        """Equal time for a PT method: its spp candidates at most ``max_pt_spp``."""
        knob = METHODS[name].knob
        spp = None if max_pt_spp is None or knob is None else \
            [c for c in knob.candidates if c <= max_pt_spp]
        return TimeBudget(ms=ms, allow_loaded=allow_loaded, candidates=spp)

    for _name, entry in entries:
        if entry.role != "matched" or entry.label not in summaries \
                or entry.label not in report.bounds["pt_at"]:
            continue
        summary = summaries[entry.label]
        if summary.result.timing_flags and not allow_loaded:
            report.left_out.append(Skipped(
                method=entry.label, label=f"PT rows at {entry.label}'s time",
                reason=f"{entry.label}'s run was timed on a loaded machine, so its frame time "
                       "is no budget (--allow-loaded uses it): "
                       + "; ".join(summary.result.timing_flags)))
            continue
        ms = 1e3 * summary.timings["seconds_per_frame"]
        pt_eq = run(f"{paper} (= {entry.label} time)", BASELINE, {"max_depth": max_depth},
                    budget=pt_budget(BASELINE, ms))
        candidates: dict[str, RunSummary] = {}
        for name in chosen:
            found = run(f"{strongest_label}: {METHODS[name].label or name} "
                        f"(= {entry.label} time)", name,
                        {"max_depth": max_depth, **STRONGEST_PT_PARAMS},
                        budget=pt_budget(name, ms))
            if found is not None:       # the PT core renders every scene: left out, loaded
                candidates[name] = found
        if pt_eq is None or (chosen and not candidates):
            continue
        report.equal_time += [
            _row(entry.label, summary),
            _row(f"{paper} {pt_eq.spec.spp} spp (= {entry.label} time)", pt_eq,
                 "; ".join(caveats(pt_eq.metrics["calibration"])))]
        if not candidates:
            continue
        best = min(candidates, key=lambda name: _mrse(candidates[name]))
        best_run = candidates[best]
        lowest = (f"lowest MRSE at this time of {', '.join(candidates)} with throughput "
                  "roulette")
        report.equal_time.append(
            _row(f"{strongest_label}: {METHODS[best].label or best} {best_run.spec.spp} spp "
                 f"(= {entry.label} time)", best_run,
                 "; ".join([lowest, *caveats(best_run.metrics["calibration"])])))
    return report


def _mrse(summary: RunSummary) -> float:
    """A run's MRSE for choosing the strongest PT; a withheld one never wins."""
    value = summary.result.mrse
    return value if value is not None and np.isfinite(value) else np.inf
