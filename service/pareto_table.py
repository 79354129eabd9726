"""The table ``nirc-bench pareto`` prints: every point's time, errors, front and speed-ups
(headed with the baseline they are against), whether its run was reused, and the
strongest PT's envelope."""

from __future__ import annotations

from typing import Any

from rich.console import Group
from rich.table import Table
from rich.text import Text

from jobs.pareto.pareto import LOADED_REASON, PARETO_METRICS
from jobs.pareto.plan import PAPER_PT, STRONGEST_PT
from jobs.pareto.tradeoff import Speedup


def _ms(seconds: float) -> str:
    return f"{1e3 * seconds:.3g}"


def _speedup(value: Speedup | None) -> str:
    """'2.31 [1.9, 2.8]', '> 4.1 [3.6, –]', '< 0.5' or 'n/a'; '' for a baseline point."""
    if value is None:
        return ""
    if not value.ci95:
        return value.text()
    ends = ["–" if end is None else f"{end:.3g}" for end in value.ci95]
    return f"{value.text()} [{ends[0]}, {ends[1]}]"


def _projected(projection: dict[str, Any] | None) -> str:
    if not projection or projection.get("frame_s") is None:
        return "n/a"
    lo, hi = projection["frame_ci"]
    return f"{_ms(projection['frame_s'])} [{_ms(lo)}, {_ms(hi)}]"


def _baseline_lines(baselines: dict[str, Any]) -> list[str]:
    """What the paper's PT and the strongest PT are, and where each candidate is lowest."""
    paper, strongest = baselines[PAPER_PT], baselines[STRONGEST_PT]
    lines = [f"{paper['label']}: {paper['definition']}.",
             f"{strongest['label']}: per time, the lowest error of "
             f"{', '.join(strongest['candidates'])} (docs/pareto.md, 'The strongest PT')."]
    for metric in PARETO_METRICS:
        pieces = strongest["envelope"][metric.field]
        lines.append(f"{strongest['label']} ({metric.label}): " + (", ".join(
            f"{p['series']} {_ms(p['from_s'])}–{_ms(p['to_s'])} ms" for p in pieces)
            or "no time interval (no candidate's front has two points)"))
    return lines


def pareto_table(result: Any) -> Group:
    """The points in time order within each series, front marked '*', a reused run
    marked '=' after its id, a time taken on a loaded machine 'L', then the notes."""
    table = Table(title=f"error against time on {result.spec.scene} "
                        f"({result.spec.resolution}x{result.spec.resolution}, "
                        f"{result.spec.frames} frames, K = {result.spec.seeds}; {result.device})")
    projected = result.spec.project_res
    target = "x".join(map(str, projected)) if projected else ""
    columns = ["series", "point", "run", "ms/frame", "spread (ms)", "run ms",
               "harness %"]
    if projected:
        columns.append(f"ms/frame at {target} (projected) [95% CI]")
    for column in columns:
        table.add_column(column, justify="left" if column in ("series", "point") else "right")
    against = result.baselines["speedups_against"]
    for metric in PARETO_METRICS:
        table.add_column(metric.label, justify="right")
        table.add_column(f"x {against} at equal {metric.label} [95% CI]", justify="right")
    notes: dict[tuple[str, str], list[str]] = {}    # (point, note) -> metrics
    for point in result.points:
        flags = [*point.probe_flags, *point.timing_flags]
        run_time = point.run_seconds_per_frame
        cells = [point.series, point.label, f"{point.id}{'=' if point.reused else ''}",
                 _ms(point.seconds_per_frame) + ("L" if point.loaded else "")
                 + ("!" if point.probe_flags else ""),
                 f"{_ms(point.seconds_spread[0])}–{_ms(point.seconds_spread[1])}",
                 "–" if run_time is None else
                 _ms(run_time) + ("L" if point.timing_flags else ""),
                 "-" if point.harness_share is None else f"{100 * point.harness_share:.0f}"]
        if projected:
            cells.append(_projected(point.projection))
        for flag in flags:
            notes.setdefault((point.label, flag), []).append("time")
        for note in (point.projection or {}).get("notes", []):
            notes.setdefault((point.label, f"projection: {note}"), []).append("time")
        for metric in PARETO_METRICS:
            key = metric.field
            value = getattr(point, key)
            found = getattr(point, f"speedup_{key}")
            front = "*" if getattr(point, f"front_{key}") else ""
            cells += ["–" if value is None else f"{value:.4g}{front}", _speedup(found)]
            if found is not None and found.note and found.note != LOADED_REASON:
                notes.setdefault((point.label, found.note), []).append(metric.label)
        table.add_row(*cells)
    work = result.work
    lines = ["* on the Pareto front of that error against time. ms/frame: the point's time, "
             "online training included (median of the interleaved timing rounds; spread: "
             "their min–max); run ms: the stored run's own ms/frame (its median frame, as "
             "render, runs and the dashboard show it; docs/pareto.md).",
             "L: timed on a loaded machine; such a point is on no front, gets no speed-up "
             "and is on no baseline's curve unless --allow-loaded "
             f"({'allowed' if result.spec.allow_loaded else 'left out'} in this call).",
             f"= run reused (stored by an earlier call under the same spec, scene, reference "
             f"and device; its timing is measured again): {work['points_reused']} reused, "
             f"{work['points_rendered']} rendered now.",
             f"x {against}: the {against}'s time at equal error (log-log interpolation of its "
             f"curves, never extrapolated: '>' / '<' are bounds) / the point's time; 95% CI: "
             f"percentile bootstrap over seeds and timing samples "
             f"({result.bootstrap['resamples']} resamples, docs/pareto.md); '–': an end the "
             f"{against}'s measured range cannot bound.",
             *_baseline_lines(result.baselines),
             "harness %: the share of the run's median frame outside kernels (host work, "
             "tracing, launch gaps); ! after ms/frame: a timing flag below.",
             *(f"left out: {item['label']}: {item['reason']}" for item in result.left_out),
             *([f"projected: the per-stage cost model (a + b x size per stage, fitted at "
                f"{', '.join(f'{r}x{r}' for r in result.spec.cost_resolutions)} on "
                f"{result.device}) evaluated at {target}: a projection from this device, not "
                f"a measurement; the errors are those measured at "
                f"{result.spec.resolution}x{result.spec.resolution} (a cache's error depends on "
                "the resolution)."] if projected else []),
             *(f"without {stage}: each point that ran it, its time less the {stage} stage "
               f"of the frames its samples are; not the method's whole cost, so never on a "
               f"front ({len(labels)} points)" if labels else
               f"without {stage}: no point ran a stage '{stage}'"
               for stage, labels in result.timing.get("without_stages", {}).items()),
             *result.timing.get("flags", []),
             *(f"{label} ({', '.join(metrics)}): {note}"
               for (label, note), metrics in notes.items()),
             *(f"skipped {s['method']}: {s['reason']}" for s in result.skipped)]
    if result.files:
        lines.append("written: " + ", ".join(result.files.values()))
    return Group(table, *(Text(line) for line in lines))
