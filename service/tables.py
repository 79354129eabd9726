"""Rich tables printed by the CLI."""

from __future__ import annotations

import json
from collections import Counter
from typing import TYPE_CHECKING, Any

from rich.console import Group
from rich.markup import escape
from rich.table import Table
from rich.text import Text

from jobs.protocol.calibration import ADVICE
from jobs.protocol.results import ReportRow, RunResult, RunResultDetail
from jobs.views.animation_comparison import ANIMATION_KEY
from metrics.bias_intervals import PER_CACHE
from metrics.denoised import DENOISER_KEY
from metrics.registry import (
    BY_NAME,
    LISTED,
    METRICS,
    PER_SEED,
    Aggregate,
    Metric,
    below_noise_floor,
    metric_interval,
    within_noise,
)
from renderers.load import stall_text
from service.animation_tables import animation_comparison_tables, animation_tables

if TYPE_CHECKING:
    from jobs.pareto.report import Report
    from jobs.sweeps.sweep import SweepResult
    from jobs.views.comparison import RunComparison


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list | tuple) and all(isinstance(v, float) for v in value):
        return "[" + ", ".join(f"{v:.4g}" for v in value) + "]"
    return str(value)


def key_value_table(title: str, values: dict[str, Any]) -> Table:
    table = Table(title=title, show_header=False)
    table.add_column("name", style="bold")
    table.add_column("value")
    for name, value in values.items():
        table.add_row(name, _fmt(value))
    return table


def scenes_table(scenes: list[Any]) -> Table:
    table = Table(title="built-in scenes")
    for column in ("name", "fingerprint", "emitters", "env map", "glossy", "delta", "description"):
        table.add_column(column)
    for scene in scenes:
        f = scene.features
        table.add_row(scene.name, scene.fingerprint, str(f.emitter_count), _yes(f.has_envmap),
                      _yes(f.has_glossy), _yes(f.has_delta), scene.description)
    return table


def _yes(flag: bool) -> str:
    return "yes" if flag else "-"


def reference_table(info: dict[str, Any]) -> Table:
    floor = info.get("split_half", {})
    return key_value_table("reference", {
        "scene": info["scene"], "fingerprint": info["fingerprint"], "key": info["key"],
        "spp": info["spp"], "reused": info["reused"],
        "floor: half-vs-half MRSE": floor.get("half_vs_half_mrse"),
        "floor: reference MRSE (est.)": floor.get("reference_mrse_estimate"),
        "file": info["path"],
    })


def verdict_text(quality: dict[str, Any]) -> str:
    """A run's quality verdict and its reasons, one line each ('ok' when none)."""
    reasons = quality.get("reasons", [])
    return "\n".join([quality.get("verdict", "not judged (stored before verdicts)"),
                      *(f"{r['code']}: {r['message']}" for r in reasons)])


def _shown(value: Any) -> Any:
    """A metric as shown: None is a value the quality verdict withheld."""
    return "withheld" if value is None else value


def metric_label(metric: Metric) -> str:
    """``metric``'s label with its unit and which way is better, e.g. 'PSNR (dB, higher better)'."""
    notes = [metric.unit] if metric.unit else []
    return f"{metric.label} ({', '.join([*notes, metric.direction + ' better'])})"


def _ci_text(ci: Any) -> str:
    return f"[{ci[0]:.4g}, {ci[1]:.4g}]" if isinstance(ci, list | tuple) else str(ci)


def metric_text(key: str, value: Any) -> str:
    """A stored metric as shown: a negative noise-corrected estimate reads 'below the
    noise floor (value)' (metrics.registry.below_noise_floor), not as a small error."""
    return f"below the noise floor ({_fmt(value)})" if below_noise_floor(key, value) \
        else _fmt(value)


def value_text(key: str, value: Any, ci: Any) -> str:
    """A stored metric with its 95 % interval: '0.012 [0.004, 0.02]', and 'within noise'
    before a noise-corrected one whose interval holds 0 (metrics.registry.within_noise);
    without an interval as :func:`metric_text` shows it."""
    if not ci:
        return metric_text(key, value)
    text = f"{_fmt(value)} [{_fmt(ci[0])}, {_fmt(ci[1])}]"
    return f"within noise: {text}" if within_noise(key, value, ci) else text


def _metric_rows(m: dict[str, Any], run: RunResultDetail) -> dict[str, Any]:
    """The run table's rows of every registered metric (values as :func:`_shown` gives
    them), each interval with how it was made or why there is none."""
    rows: dict[str, Any] = {}
    for metric in _computed(METRICS, run):
        absent = "n/a (K = 1)" if metric.needs_k2 else "-"
        if metric.aggregate is Aggregate.PER_CACHE and not run.caches:
            continue    # a method without a cache has no per-cache statistics
        rows[metric_label(metric)] = metric_text(metric.key, m.get(metric.key, absent))
        if metric.ci_key:
            ci, note = metric_interval(metric, run.metrics)
            rows[f"{metric.label} 95% CI"] = f"{_ci_text(ci)} ({note})" if ci else note or "-"
            if metric.name == "rbias2" and run.bias_verdict:
                rows["rBias² verdict"] = run.bias_verdict
        for label, key in metric.details:
            rows[label] = metric_text(key, m.get(key, absent))
    return rows


def _computed(metrics: tuple[Metric, ...], run: RunResultDetail) -> list[Metric]:
    """``metrics`` less those of a run option ``run`` did not ask for (``Metric.requires``)."""
    return [m for m in metrics if m.requires is None or m.requires in run.metrics]


def metrics_table(run: RunResultDetail) -> Group:
    """The method-vs-reference table of a stored run (jobs.protocol.results), then one row
    per seed; the metrics the quality verdict withholds read 'withheld'."""
    t = run.timings
    m = {key: _shown(value) for key, value in run.metrics.items()}
    reference = run.reference
    head = {
        "quality verdict": verdict_text(run.quality),
        "run": run.id,
        "scene / method": f"{run.scene} / {run.method_label or run.method}",
        "scene content (fingerprint)": run.scene_fingerprint,
        **({"XML settings not used": "\n".join(run.scene_overrides)}
           if run.scene_overrides else {}),
        "resolution": "x".join(map(str, run.resolution)),
        "spp x frames": f"{run.spp} x {run.frames}",
        "seeds (K)": run.seeds,
        "eps of the relative errors": m.get("eps", "-"),
        "reference": f"{reference_text(reference)} (reference {reference.id})"
        if reference else "-",
        "reference floor MRSE (est.)":
            reference.split_half.get("reference_mrse_estimate") if reference else None,
        "reference floor mean Var[R]/(R2+eps)": m.get("ref_floor"),
        "floor / rBias2, floor / MRSE": f"{_fmt(run.ref_floor_ratio_rbias2)}, "
                                        f"{_fmt(run.ref_floor_ratio_mrse)}",
        **_metric_rows(m, run),
        **({"denoiser": _denoiser_text(run.metrics[DENOISER_KEY])}
           if DENOISER_KEY in run.metrics else {}),
        "ms per frame": _ms(run.seconds_per_frame),
        "kernel ms / harness share": _device_text(run),
        "ms render stage": _ms(run.render_seconds_per_frame),
        "warm-up / compile (s)": _warmup_text(t),
        "machine load while timed": _load_text(t.get("load")),
        "avg path vertices": run.path_stats.get("avg_path_vertices"),
        "non-finite pixels": run.quality.get("nonfinite_pixels"),
        "device": run.device_key,
        "estimator / metric version": f"{run.estimator_version} / {run.metric_version}",
    }
    seeds = Table(title="per seed")
    per_seed = _computed(PER_SEED, run)
    for column in ("seed", *(m.label for m in per_seed), "ms/frame", "non-finite"):
        seeds.add_column(column, justify="right")
    for s in run.per_seed:
        seeds.add_row(str(s.seed), *(_fmt(_shown(s.metrics.get(m.seed_key))) for m in per_seed),
                      _fmt(_ms(s.metrics.get("seconds_per_frame"))),
                      str(s.metrics.get("nonfinite_pixels")))
    parts: list[Any] = [key_value_table(
        escape(f"{run.method_label or run.method} vs reference ({reference_text(reference)})"),
        head)]
    if run.time_breakdown_ms:
        parts.append(stage_table(run))
    parts.append(seeds)
    parts += [f"warning: {text}" for text in [*run.warnings, *run.timing_flags]]
    if (note := per_cache_sum_note(run.metrics)) is not None:
        parts.append(note)
    if m.get("calibration"):
        parts.append(calibration_table("equal-time calibration", m["calibration"]))
    if ANIMATION_KEY in run.metrics:
        parts.append(animation_tables(run.metrics[ANIMATION_KEY]))
    return Group(*parts)


def per_cache_sum_note(metrics: dict[str, Any]) -> str | None:
    """Why a cache method's rBias² + rVar is not its MRSE, in one line (None for a pooled
    rBias²): rBias² is the caches' mean, rVar and MRSE are pooled over the seeds, so
    rBias² + rVar = MRSE - ref floor + (rBias² - pooled rBias²) (docs/metrics.md,
    "K independent renders")."""
    if metrics.get("rbias2_basis") != PER_CACHE:
        return None
    per_cache, pooled = metrics.get("rbias2"), metrics.get("rbias2_pooled")
    excess = (f" = {_fmt(per_cache - pooled)}"
              if isinstance(per_cache, float) and isinstance(pooled, float) else "")
    return ("note: rBias² is the caches' mean (t-interval), rVar and MRSE are pooled over "
            "seeds: rBias² + rVar = MRSE - ref floor + (rBias² - pooled rBias²"
            f"{excess}), the caches' bias spread (docs/metrics.md)")


def _denoiser_text(denoiser: dict[str, Any]) -> str:
    """What denoised a run (metrics.denoised.denoiser_provenance), in one line."""
    return (f"{denoiser['library']} {denoiser['version']} ({denoiser['filter']} filter, "
            f"{denoiser['quality']} quality, features at {denoiser['feature_spp']} spp) of "
            f"each seed's last {denoiser['accumulated_frames']} frames; "
            f"{denoiser['seeds_denoised']} seeds denoised (see each seed's denoised_note)")


def reference_text(reference: Any) -> str:
    """What a run's reference is: its integrator, spp and depth ('-' without one)."""
    if reference is None:
        return "-"
    parts = [reference.integrator, f"{reference.spp} spp",
             None if reference.max_depth is None else "unbounded depth"
             if reference.max_depth == -1 else f"max_depth {reference.max_depth}"]
    return ", ".join(part for part in parts if part)


def _device_text(run: RunResult) -> str:
    if run.kernel_seconds_per_frame is None or run.harness_share is None:
        return "- (no kernel time: stored before it was measured)"
    return f"{_fmt(_ms(run.kernel_seconds_per_frame))} / {100 * run.harness_share:.0f} %"


def _warmup_text(timings: dict[str, Any]) -> str:
    compile_s = timings.get("compile_s")
    compiled = (f"compile {compile_s:.3g} (kernel history)" if compile_s is not None else
                f"compile {timings['compile_s_estimate']:.3g} (estimated)")
    return f"warm-up {timings['warmup_s']:.3g}, {compiled}"


def _load_text(load: dict[str, Any] | None) -> str:
    if not load:
        return "- (not measured)"
    verdict = {True: "LOADED", False: "quiet", None: "unknown"}[load["loaded"]]
    windows = load.get("windows") or [load]
    stalls = [w["cpu_stall_fraction"] for w in windows if w.get("cpu_stall_fraction") is not None]
    detail = f" ({stall_text(max(stalls))})" if stalls else ""
    return verdict + detail


def stage_table(run: RunResult) -> Table:
    """The median frame by stage: wall milliseconds, split into kernel and harness by the
    stage's kernel share of the median kernel frame (jobs.protocol.results.device_split:
    kernel + harness is the wall time, whatever the kernel frames cost), launches."""
    wall = run.time_breakdown_ms or {}
    kernel = run.kernel_breakdown_ms or {}
    harness = run.harness_breakdown_ms or {}
    stages = (run.timings if isinstance(run, RunResultDetail) else {}).get("stages", {})
    table = Table(title="the median frame by stage (ms; its wall split into kernel and "
                        "harness (host work, tracing, launch gaps) by the stage's kernel "
                        "share of the median kernel frame)")
    for column in ("stage", "wall", "kernel", "harness", "harness %", "launches"):
        table.add_column(column, justify="left" if column == "stage" else "right")
    for name, ms in wall.items():
        k, h = kernel.get(name), harness.get(name)
        launches = (stages.get(name) or {}).get("launches_median")
        table.add_row(name, _fmt(ms), "-" if k is None else _fmt(k),
                      "-" if h is None else _fmt(h),
                      "-" if k is None or h is None or k + h <= 0
                      else f"{100 * h / (k + h):.0f}",
                      "-" if launches is None else str(launches))
    return table


def breakdown_table(title: str, rows: list[ReportRow]) -> Table:
    """Milliseconds per frame of each part of the rows' median frames (the NIRC paper's
    Table 1), their total (the stages), its kernel time and harness share (of the same
    frame: jobs.protocol.results.device_split)."""
    parts = list(dict.fromkeys(name for r in rows for name in (r.time_breakdown_ms or {})))
    table = Table(title=title)
    for column in ("method", *parts, "total", "kernel", "harness %"):
        table.add_column(column, justify="left" if column == "method" else "right")
    for r in rows:
        ms = r.time_breakdown_ms or {}
        table.add_row(r.label, *(_fmt(ms[name]) if name in ms else "-" for name in parts),
                      _fmt(_ms(r.seconds_per_frame)), _fmt(_ms(r.kernel_seconds_per_frame)),
                      "-" if r.harness_share is None else f"{100 * r.harness_share:.0f}")
    return table


def _ms(seconds: float | None) -> float | None:
    return None if seconds is None else 1e3 * seconds


def _metric_cells(row: RunResult) -> list[str]:
    """A result row's listed metrics (metrics.registry), each with its 95 % interval."""
    cells = []
    for m in LISTED:
        value = getattr(row, m.field)
        ci = getattr(row, f"{m.field}_ci95") if m.ci_key else None
        cells.append("-" if value is None else value_text(m.key, value, ci))
    return cells


def comparison_tables(report: Report) -> Group:
    """The Fig. 7 comparison: one table at equal spp, one at equal time."""
    def table(title: str, rows: list[ReportRow]) -> Table:
        t = Table(title=title)
        for column in ("method", "run", "spp", *(m.label for m in LISTED), "ms/frame",
                       "ms render stage", "note"):
            t.add_column(column, justify="left" if column in ("method", "note") else "right")
        for r in rows:
            loaded = " L" if r.timing_flags else ""
            t.add_row(r.label, str(r.id), str(r.spp), *_metric_cells(r),
                      _fmt(_ms(r.seconds_per_frame)) + loaded,
                      _fmt(_ms(r.render_seconds_per_frame)) + loaded,
                      "; ".join(filter(None, [r.note, *r.timing_flags])))
        return t

    return Group(table(f"{report.scene}: equal spp ({report.device})", report.equal_spp),
                 table(f"{report.scene}: equal time ({report.device})", report.equal_time),
                 breakdown_table(f"{report.scene}: ms per frame by part (the median frame; "
                                 "render includes cache inference unless listed)",
                                 report.equal_spp),
                 # None when the calibration was left out (loaded machine) or not run.
                 *([calibration_table("N_c calibration (NIRC biased)", report.calibration)]
                   if report.calibration else []),
                 *(f"skipped {s.label or s.method}: {s.reason}" for s in report.skipped),
                 *(["L: timed on a loaded machine (the note says how loaded)"]
                   if any(r.timing_flags for r in [*report.equal_spp, *report.equal_time])
                   else []),
                 *(f"left out {s.label or s.method}: {s.reason}" for s in report.left_out))


def calibration_table(title: str, cal: dict[str, Any]) -> Table:
    """An equal-time calibration record (jobs.protocol.calibration.Calibration.to_json())."""
    chosen = cal["chosen"] if cal["fits"] else f"{cal['chosen']} (none fits: over budget)"
    if cal.get("capped"):   # records stored before the flags have none
        chosen = f"{chosen} (capped: the largest candidate fits)"
    spread = cal.get("spread_s") or {}
    timings = Counter(cal.get("order") or [])

    def ms(value: int | str, seconds: float) -> str:
        lo_hi = spread.get(str(value))
        # The search times a candidate out of play in fewer rounds (jobs.protocol.calibration).
        rounds = timings[f"{cal['knob']}={value}"]
        fewer = f" ({rounds} of {cal['rounds']} rounds)" if 0 < rounds < cal.get("rounds", 0) else ""
        return (f"{value}: {1e3 * seconds:.3g}{fewer}" if not lo_hi else
                f"{value}: {1e3 * seconds:.3g} [{1e3 * lo_hi[0]:.3g}, {1e3 * lo_hi[1]:.3g}]{fewer}")

    budget = f"{cal['budget_source']} = {1e3 * cal['budget_s']:.3g} ms"
    if cal.get("budget_spread_s"):
        lo, hi = cal["budget_spread_s"]
        budget += f" [{1e3 * lo:.3g}, {1e3 * hi:.3g}]"
    rows = {
        "budget": budget,
        (escape(f"frame ms per {cal['knob']} (median [min, max] of {cal['rounds']} rounds)")
         if cal.get("rounds") else f"frame ms per {cal['knob']}"):   # old records: no rounds
            ", ".join(ms(k, s) for k, s in cal["measured_s"].items()),
        f"chosen {cal['knob']}": chosen,
        "device": cal["device_key"],
    }
    untimed: dict[str, list[str]] = {}   # why -> knob values (old records: none)
    for value, why in (cal.get("not_timed") or {}).items():
        untimed.setdefault(why, []).append(value)
    if untimed:
        rows["not timed"] = "; ".join(f"{cal['knob']} {', '.join(values)}: {why}"
                                      for why, values in untimed.items())
    if cal.get("probes_per_round"):
        frames = cal.get("timed_frames")
        rows["calibration cost"] = (
            f"{cal['wall_s']:.3g} s, "
            + (f"{frames} timed frames, " if frames is not None else "")
            + f"renders timed per round {', '.join(map(str, cal['probes_per_round']))}")
    if cal.get("unstable"):
        rows["UNSTABLE"] = "; ".join(r for r in cal.get("reasons", []) if r.startswith("unstable"))
    if cal.get("loaded"):
        rows["LOADED"] = "; ".join(r for r in cal.get("reasons", []) if r.startswith("loaded"))
    if cal.get("left_out"):
        rows["left out (loaded)"] = "; ".join(cal["left_out"])
    if cal.get("unstable") or cal.get("loaded"):
        rows["what to do"] = ADVICE.removeprefix("what to do: ")
    return key_value_table(title, rows)


#: After a time measured on a loaded machine (as the pareto table and the dashboard mark it).
LOADED_MARK = "L"
#: The sweep table's columns (SweepRow attribute, header); the metric columns (each with
#: its 95 % interval) come from metrics.registry.
SWEEP_COLUMNS = (
    ("series", "series"), ("eps", "eps"), ("nc", "N_c v1"), ("value", "value"),
    *((m.field, m.label) for m in LISTED), ("ms_frame", "ms/frame"),
    ("avg_path_length", "path len"), ("ir_bounces_pct", "% IR"),
    ("avg_path_length_authors", "path len (authors)"), ("ir_bounces_pct_authors", "% IR (authors)"),
    ("cache_at_v1_pct", "% v1 cache"), ("id", "run"),
)


def _work_line(work: dict[str, int]) -> str:
    return (f"reference {work['reference_rendered']}, caches {work['snapshots_trained']} "
            f"(reused {work['snapshots_reused']}), points {work['points_rendered']} "
            f"(reused {work['points_reused']}), calibrations {work['calibrations']}")


def same_render_runs(rows: list[Any]) -> list[tuple[Any, list[Any]]]:
    """The rows with, for each, the following rows of its series it stands for: those
    with its render key (jobs.sweeps.sweep.SweepRow.render_key: the same method,
    parameters, v1 masks and caches), which render the same images whatever their eps.
    Other rows, and rows stored without a render key, stand for themselves."""
    shown: list[tuple[Any, list[Any]]] = []
    for row in rows:
        if shown:
            first, alike = shown[-1]
            if (row.series == first.series and row.render_key is not None
                    and row.render_key == first.render_key):
                alike.append(row)
                continue
        shown.append((row, []))
    return shown


def sweep_table(result: SweepResult) -> Group:
    """The sweep's points (one row per series and eps / N_c / value), skipped methods,
    work done. Rows that render what the row before them renders are shown once, and said
    so (:func:`same_render_runs`; the JSON keeps every point). A parameter sweep shows
    its value column instead of eps and N_c at v1."""
    table = Table(title=f"sweep {result.sweep_id}: {result.scene} on {result.device_key}")
    # A parameter sweep's points have no eps and no N_c at v1 of their own (they read '-').
    hidden = {"eps", "nc"} if result.kind == "parameter" else {"value"}
    columns = [(key, header) for key, header in SWEEP_COLUMNS if key not in hidden]
    for key, header in columns:
        # The series label is what a reader looks rows up by: never wrapped.
        header = result.parameter or header if key == "value" else header
        table.add_column(header, justify="left" if header == "series" else "right",
                         no_wrap=header == "series")
    metric_cells = {m.field: index for index, m in enumerate(LISTED)}
    collapsed: list[str] = []
    shown = same_render_runs(result.rows) if result.kind != "parameter" \
        else [(row, []) for row in result.rows]      # each value is a point of its own
    for row, alike in shown:
        metrics = _metric_cells(row)
        cells = []
        for key, _ in columns:
            value = getattr(row, key)
            if key in metric_cells:
                cells.append(metrics[metric_cells[key]])
            elif key == "ms_frame" and row.timing_flags:
                cells.append(f"{_fmt(value)} {LOADED_MARK}")
            elif key == "nc" and (row.calibration_capped or row.calibration_unstable):
                flags = [name for name in ("capped", "unstable")
                         if getattr(row, f"calibration_{name}")]
                cells.append(f"{_fmt(value)} ({', '.join(flags)})")
            else:
                cells.append("-" if value is None else _fmt(value))
        if not row.finite:
            cells[0] += " (non-finite pixels!)"
        if alike:
            cells[1] = f"{_fmt(row.eps)}–{_fmt(alike[-1].eps)}"
            collapsed.append(
                f"{row.series}: eps {_fmt(row.eps)} to {_fmt(alike[-1].eps)} shown as one row: "
                f"these {len(alike) + 1} points render the same images (the same parameters, "
                f"caches and v1 masks, which allow {_fmt(row.mask_pct)} % of pixels) "
                f"(runs {', '.join(str(r.id) for r in [row, *alike])}; --json lists each)")
        table.add_row(*(escape(cell) for cell in cells))
    lines: list[Any] = [table, *(Text(line) for line in collapsed)]
    if any(row.timing_flags for row in result.rows):
        lines.append(f"{LOADED_MARK} after ms/frame: timed on a loaded machine (`nirc-bench "
                     "runs show RUN` says how loaded); its time is not comparable")
    lines += [f"skipped {s.method}: {s.reason}" for s in result.skipped]
    if result.stage_work:
        lines.append(f"rendered by its stage jobs: {_work_line(result.stage_work)}")
        lines.append(f"rendered by the sweep job: {_work_line(result.work)}")
    else:
        lines.append(f"rendered: {_work_line(result.work)}")
    lines += [f"{name}: {path}" for name, path in result.files.items()]
    return Group(*lines)


def _flat(values: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested settings as 'a.b' rows."""
    rows: dict[str, Any] = {}
    for name, value in values.items():
        if isinstance(value, dict) and value:
            rows.update(_flat(value, f"{prefix}{name}."))
        else:
            rows[f"{prefix}{name}"] = value
    return rows


def _plain_table(title: str, values: dict[str, Any]) -> Table:
    """:func:`key_value_table` of values shown as text, never read as rich markup."""
    return key_value_table(escape(title), {escape(k): escape(_fmt(v)) for k, v in values.items()})


def run_details_tables(run: RunResultDetail) -> Group:
    """Everything stored about a run: the run table (metrics aggregated and per seed,
    timings), its resolved method parameters, each cache's configuration, its provenance
    and the settings of its reference."""
    parts: list[Any] = [metrics_table(run)]
    labels = {"name": run.name, **{f"tag {k}": v for k, v in run.tags.items()}}
    if any(v is not None for v in labels.values()):
        parts.append(_plain_table("name and tags", labels))
    parts.append(_plain_table(f"{run.method} parameters (resolved)", _flat(run.params)))
    for name, cache in run.caches.items():
        parts.append(_plain_table(f"cache '{name}' configuration", _flat(cache)))
    parts.append(_plain_table("provenance", {
        "created": run.created_at, "commit": run.git_commit, "branch": run.git_branch,
        "device": run.device_key, **_flat(run.device, "device."),
        **_flat(run.versions, "version.")}))
    reference = run.reference
    if reference is not None:
        parts.append(_plain_table(f"reference {reference.id}", {
            "integrator": reference.integrator, "spp": reference.spp,
            "max_depth": reference.max_depth, "passes": reference.passes,
            "relative std. error reached": reference.rel_stderr, "key": reference.key,
            **_flat(reference.split_half, "split-half ")}))
    return Group(*parts)


def _row_value(row: RunResult, key: str, field: str | None) -> str:
    """A result row's listed metric with its 95 % interval (:func:`value_text`)."""
    value = getattr(row, field) if field else None
    if value is None:
        return "-"
    return value_text(key, value, getattr(row, f"{field}_ci95", None))


def _difference_text(run: RunResult, setting: str, value: Any) -> str:
    """A compared setting's value for ``run``: a parameter its method does not have reads
    so, not 'None' (pt beside nirc has no nc)."""
    name = setting.removeprefix("params.")
    if name != setting and name not in run.params:
        return f"- (not a {run.method} parameter)"
    return _fmt(value)


def comparison_table(comparison: RunComparison) -> Group:
    """Runs side by side: what differs between them, then each later run's metrics
    against the first's with the interval of the change."""
    rows = comparison.runs
    by_id = {r.id: r for r in rows}
    head = Table(title="runs compared (the first is the baseline)")
    for column in ("setting", *(f"run {r.id}" for r in rows)):
        head.add_column(column)
    head.add_row("what ran", *(escape(r.method_label) for r in rows))
    head.add_row("name", *(escape(r.name or "-") for r in rows))
    head.add_row("created", *(r.created_at.strftime("%Y-%m-%d %H:%M") for r in rows))
    for setting, values in comparison.differences.items():
        head.add_row(escape(setting), *(escape(_difference_text(r, setting, v))
                                        for r, v in zip(rows, values, strict=True)))
    if not comparison.differences:
        head.add_row("(settings)", *("the same" for _ in rows))
    standings = comparison.standings
    if standings:
        head.add_row("ms / frame", *(_fmt(s.ms_per_frame) if s.ms_per_frame else "-"
                                     for s in standings))
        head.add_row("efficiency [1/s] (95% CI)", *(
            "-" if s.efficiency is None else
            f"{_fmt(s.efficiency)} {_ci_text(s.efficiency_ci95) if s.efficiency_ci95 else ''}"
            for s in standings))
        head.add_row("timing", *(escape("; ".join(s.timing_flags)) or "not loaded"
                                 for s in standings))
        head.add_row("quality verdict", *(escape(s.verdict or "-") for s in standings))
        head.add_row("rBias²", *(f"{s.bias_verdict or '-'} ({s.rbias2_basis or '-'})"
                                 for s in standings))
    parts: list[Any] = [head]
    for delta in comparison.deltas:
        table = Table(title=f"run {delta.run} against run {delta.baseline}")
        for column in ("metric", f"run {delta.baseline}", f"run {delta.run}", "change",
                       "ratio", "95% interval of the change", "differs", "note"):
            table.add_column(column, justify="left" if column in ("metric", "note")
                             else "right")
        for m in delta.metrics:
            field = BY_NAME[m.metric].field
            cells = [_row_value(by_id[run_id], m.key, field)
                     for run_id in (delta.baseline, delta.run)]
            table.add_row(f"{m.label} ({m.direction} better)", *cells, *(
                "-" if v is None else metric_text("", v) for v in (m.delta, m.ratio)),
                          escape(_ci_text(m.delta_ci95)) if m.delta_ci95 else "-",
                          "-" if m.differs is None else "yes" if m.differs else "no",
                          m.interval_note)
        parts.append(table)
    parts += [animation_comparison_tables(delta) for delta in comparison.animation]
    parts.append(f"note: {comparison.note}")
    return Group(*parts)


def reuse_line(result: RunResultDetail) -> str:
    """What a render that found its run stored says: which run, from when, made by what,
    and whether its timing can be trusted."""
    flags = "; ".join(result.timing_flags) or "none"
    return (f"reused run {result.id}, stored {result.created_at:%Y-%m-%d %H:%M} UTC: the same "
            f"spec by commit {result.git_commit}, estimator v{result.estimator_version} on "
            f"{result.device_key} (its timing flags: {flags}); --rerun renders it again")


def render_tables(summary: Any) -> Group:
    """What ``render`` prints of its RunSummary (jobs.protocol.executor): the run table,
    after the line saying it was reused when it was."""
    table = metrics_table(summary.result)
    return Group(Text(reuse_line(summary.result)), table) if summary.reused else table


def methods_table(infos: list[dict[str, Any]]) -> Group:
    """The registered methods (service.method_info): one table of all, or with one
    method the table of its parameters and defaults."""
    if len(infos) > 1:
        table = Table(title="methods (nirc-bench methods NAME: its parameters)")
        for column in ("name", "what it is", "needs of a scene", "equal-time knob"):
            table.add_column(column)
        for info in infos:
            table.add_row(info["name"], escape(info["description"]), escape(info["needs"]),
                          info["knob"] or "-")
        return Group(table)
    info = infos[0]
    table = Table(title=escape(f"{info['name']}: {info['description']}"))
    for column in ("parameter", "type", "default", "what it is"):
        table.add_column(column)
    for param in info["params"]:
        table.add_row(param["name"], escape(param["type"]),
                      escape(json.dumps(param["default"])) if isinstance(
                          param["default"], dict | list) else escape(str(param["default"])),
                      escape(param["help"]))
    lines = [f"needs of a scene: {info['needs']}",
             f"equal-time knob: {info['knob'] or '-'}; estimator version {info['version']}",
             "set a parameter with render --param NAME=VALUE (JSON values)"]
    return Group(table, *(Text(line) for line in lines))
