"""Rich tables printed by the CLI."""

from __future__ import annotations

from typing import Any

from rich.console import Group
from rich.markup import escape
from rich.table import Table

from metrics.registry import LISTED, METRICS, PER_SEED, Metric


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


def _metric_rows(m: dict[str, Any]) -> dict[str, Any]:
    """The run table's rows of every registered metric (values as :func:`_shown` gives them)."""
    rows: dict[str, Any] = {}
    for metric in METRICS:
        absent = "n/a (K = 1)" if metric.needs_k2 else "-"
        rows[metric_label(metric)] = m.get(metric.key, absent)
        if metric.ci_key:
            rows[f"{metric.label} 95% CI"] = _ci_text(m.get(metric.ci_key, "n/a (K = 1)"))
        for label, key in metric.details:
            rows[label] = m.get(key, absent)
    return rows


def metrics_table(summary: Any) -> Group:
    """The method-vs-reference table of a run, then one row per seed; the metrics the
    quality verdict withholds read 'withheld'."""
    spec, t = summary.spec, summary.timings
    m = {key: _shown(value) for key, value in summary.metrics.items()}
    head = {
        "quality verdict": verdict_text(summary.quality),
        "run": summary.run_id,
        "scene / method": f"{spec.scene} / {spec.method}",
        "resolution": f"{spec.resolution}x{spec.resolution}",
        "spp x frames": f"{spec.spp} x {spec.frames}",
        "seeds (K)": spec.seeds,
        "reference": f"{summary.reference['spp']} spp"
                     + (" (reused)" if not summary.reference["rendered_now"] else " (rendered)"),
        "reference floor MRSE (est.)": summary.reference["split_half"].get("reference_mrse_estimate"),
        "reference floor mean Var[R]/(R2+eps)": m.get("ref_floor"),
        "floor / rBias2, floor / MRSE": f"{_fmt(m.get('ref_floor_ratio_rbias2'))}, "
                                        f"{_fmt(m.get('ref_floor_ratio_mrse'))}",
        **_metric_rows(m),
        "ms per frame": 1e3 * t["seconds_per_frame"],
        "warm-up / compile (s)": f"{t['warmup_s']:.3g} / {t['compile_s_estimate']:.3g}",
        "avg path vertices": summary.path_stats["avg_path_vertices"],
        "non-finite pixels": summary.quality["nonfinite_pixels"],
        "device": summary.device["device_key"],
        "estimator / metric version": f"{summary.estimator_version} / {summary.metric_version}",
    }
    seeds = Table(title="per seed")
    for column in ("seed", *(m.label for m in PER_SEED), "ms/frame", "non-finite"):
        seeds.add_column(column, justify="right")
    for s in summary.per_seed:
        seeds.add_row(str(s["seed"]), *(_fmt(_shown(s.get(m.seed_key))) for m in PER_SEED),
                      _fmt(1e3 * s["seconds_per_frame"]),
                      str(s["nonfinite_pixels"]))
    parts: list[Any] = [key_value_table(f"{spec.method} vs reference", head), seeds]
    parts += [f"warning: {text}" for text in m.get("warnings") or []]
    if m.get("calibration"):
        parts.append(calibration_table("equal-time calibration", m["calibration"]))
    return Group(*parts)


def comparison_tables(report: Any) -> Group:
    """The Fig. 7 comparison: one table at equal spp, one at equal time."""
    def table(title: str, rows: list[Any]) -> Table:
        t = Table(title=title)
        columns = ["method", "run", "spp"]
        for m in LISTED:
            columns += [m.label, f"{m.label} 95% CI"] if m.ci_key else [m.label]
        for column in (*columns, "ms/frame", "ms render", "note"):
            t.add_column(column, justify="left" if column in ("method", "note") else "right")
        for r in rows:
            cells = []
            for m in LISTED:
                value = getattr(r, m.field, None)
                cells.append("-" if value is None else _fmt(value))
                if m.ci_key:
                    ci = getattr(r, f"{m.field}_ci95", None)
                    cells.append(f"[{ci[0]:.3g}, {ci[1]:.3g}]" if ci else "-")
            t.add_row(r.label, str(r.run_id), str(r.spp), *cells, _fmt(r.ms_frame),
                      _fmt(r.ms_render), r.note)
        return t

    return Group(table(f"{report.scene}: equal spp ({report.device})", report.equal_spp),
                 table(f"{report.scene}: equal time ({report.device})", report.equal_time),
                 calibration_table("N_c calibration (NIRC biased)", report.calibration))


def calibration_table(title: str, cal: dict[str, Any]) -> Table:
    """An equal-time calibration record (jobs.protocol.calibration.Calibration.to_json())."""
    chosen = cal["chosen"] if cal["fits"] else f"{cal['chosen']} (none fits: over budget)"
    if cal.get("capped"):   # records stored before the flags have none
        chosen = f"{chosen} (capped: the largest candidate fits)"
    spread = cal.get("spread_s") or {}

    def ms(value: int | str, seconds: float) -> str:
        lo_hi = spread.get(str(value))
        return (f"{value}: {1e3 * seconds:.3g}" if not lo_hi else
                f"{value}: {1e3 * seconds:.3g} [{1e3 * lo_hi[0]:.3g}, {1e3 * lo_hi[1]:.3g}]")

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
    if cal.get("unstable"):
        rows["UNSTABLE"] = "; ".join(r for r in cal.get("reasons", []) if r.startswith("unstable"))
    return key_value_table(title, rows)


#: The sweep table's columns (row key, header); the metric columns come from metrics.registry.
SWEEP_COLUMNS = (
    ("series", "series"), ("eps", "eps"), ("nc", "N_c v1"),
    *((m.field, m.label) for m in LISTED), ("ms_frame", "ms/frame"),
    ("avg_path_length", "path len"), ("ir_bounces_pct", "% IR"),
    ("avg_path_length_authors", "path len (authors)"), ("ir_bounces_pct_authors", "% IR (authors)"),
    ("cache_at_v1_pct", "% v1 cache"), ("run_id", "run"),
)
#: Row key -> the row key of its 95 % interval, shown in the same cell.
_SWEEP_CI = {m.field: f"{m.field}_ci95" for m in LISTED if m.ci_key}


def _work_line(work: dict[str, int]) -> str:
    return (f"reference {work['reference_rendered']}, caches {work['snapshots_trained']} "
            f"(reused {work['snapshots_reused']}), points {work['points_rendered']} "
            f"(reused {work['points_reused']}), calibrations {work['calibrations']}")


def sweep_table(result: Any) -> Group:
    """The sweep's points (one row per series and eps / N_c), skipped methods, work done."""
    table = Table(title=f"sweep {result.sweep_id}: {result.scene} on {result.device_key}")
    for _, header in SWEEP_COLUMNS:
        # The series label is what a reader looks rows up by: never wrapped.
        table.add_column(header, justify="left" if header == "series" else "right",
                         no_wrap=header == "series")
    for row in result.rows:
        cells = []
        for key, _ in SWEEP_COLUMNS:
            value = row.get(key)
            if key in _SWEEP_CI and row.get(_SWEEP_CI[key]):
                lo, hi = row[_SWEEP_CI[key]]
                cells.append(f"{_fmt(value)} [{_fmt(lo)}, {_fmt(hi)}]")
            elif key == "nc" and (row.get("calibration_capped") or row.get("calibration_unstable")):
                flags = [name for name in ("capped", "unstable") if row.get(f"calibration_{name}")]
                cells.append(f"{_fmt(value)} ({', '.join(flags)})")
            else:
                cells.append("-" if value is None else _fmt(value))
        if not row.get("finite", True):
            cells[0] += " (non-finite pixels!)"
        table.add_row(*cells)
    lines: list[Any] = [table]
    lines += [f"skipped {s['method']}: {s['reason']}" for s in result.skipped]
    stage_work = getattr(result, "stage_work", None)   # absent in sweeps stored before it
    if stage_work:
        lines.append(f"rendered by its stage jobs: {_work_line(stage_work)}")
        lines.append(f"rendered by the sweep job: {_work_line(result.work)}")
    else:
        lines.append(f"rendered: {_work_line(result.work)}")
    lines += [f"{name}: {path}" for name, path in result.files.items()]
    return Group(*lines)
