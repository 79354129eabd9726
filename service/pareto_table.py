"""The table ``nirc-bench pareto`` prints: every point's time, errors, front and speed-ups,
and whether its run was reused."""

from __future__ import annotations

from typing import Any

from rich.console import Group
from rich.table import Table
from rich.text import Text

from jobs.protocol.pareto import PARETO_METRICS
from jobs.protocol.tradeoff import Speedup


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


def pareto_table(result: Any) -> Group:
    """The points in time order within each series, front marked '*', a reused run
    marked '=' after its id, then the notes."""
    table = Table(title=f"error against time on {result.spec.scene} "
                        f"({result.spec.resolution}x{result.spec.resolution}, "
                        f"{result.spec.frames} frames, K = {result.spec.seeds}; {result.device})")
    for column in ("series", "point", "run", "ms/frame", "spread (ms)"):
        table.add_column(column, justify="left" if column in ("series", "point") else "right")
    for metric in PARETO_METRICS:
        table.add_column(metric.label, justify="right")
        table.add_column(f"x PT at equal {metric.label} [95% CI]", justify="right")
    notes: dict[tuple[str, str], list[str]] = {}    # (point, note) -> metrics
    for point in result.points:
        cells = [point.series, point.label, f"{point.id}{'=' if point.reused else ''}",
                 _ms(point.seconds_per_frame),
                 f"{_ms(point.seconds_spread[0])}–{_ms(point.seconds_spread[1])}"]
        for metric in PARETO_METRICS:
            key = metric.field
            value = getattr(point, key)
            found = getattr(point, f"speedup_{key}")
            front = "*" if getattr(point, f"front_{key}") else ""
            cells += ["–" if value is None else f"{value:.4g}{front}", _speedup(found)]
            if found is not None and found.note:
                notes.setdefault((point.label, found.note), []).append(metric.label)
        table.add_row(*cells)
    work = result.work
    lines = ["* on the Pareto front of that error against time. ms/frame includes online "
             "training (median of the interleaved timing rounds; spread: their min–max).",
             f"= run reused (stored by an earlier call under the same spec, scene, reference "
             f"and device; its timing is measured again): {work['points_reused']} reused, "
             f"{work['points_rendered']} rendered now.",
             f"x PT: PT's time at equal error (log-log interpolation of its curve, never "
             f"extrapolated: '>' / '<' are bounds) / the point's time; 95% CI: percentile "
             f"bootstrap over seeds and timing samples ({result.bootstrap['resamples']} "
             "resamples, docs/pareto.md); '–': an end PT's measured range cannot bound.",
             *(f"{label} ({', '.join(metrics)}): {note}"
               for (label, note), metrics in notes.items()),
             *(f"skipped {s['method']}: {s['reason']}" for s in result.skipped)]
    if result.files:
        lines.append("written: " + ", ".join(result.files.values()))
    return Group(table, *(Text(line) for line in lines))
