"""PNG plots of benchmark results, in the style of the NIRC paper.

The figures follow "Neural Two-Level Monte Carlo Real-Time Rendering" (the NIRC
paper):

* ``plot_sweep`` is the adaptive equal-bias sweep of Figure 13: the metrics
  marked ``sweep_plot`` in metrics.registry (MRSE, FLIP, relative squared bias
  rBias² and relative variance rVar) against the percentage of bounces that use
  indirect radiance, one line per method.
* ``plot_convergence`` is the error-over-frames plot of Figure 10: MRSE of each
  single frame and, optionally, of the running mean of the frames so far.
* ``plot_pareto`` is error against seconds per frame (``nirc-bench pareto``),
  log-log, one series per method, the Pareto front highlighted, the strongest PT's
  envelope one series of its own.

Colours and dashes are the charts' (jobs/views/chart_styles.py): one hue per
method family (a row's or point's ``method``), shades and dashes for its
configurations, the Pareto front black. Every panel has both axis labels, and the
left margin is widened until the y label and tick labels fit (:func:`fit_margins`).

Plotting is headless: figures are ``matplotlib.figure.Figure`` objects drawn by
the Agg canvas, never registered with pyplot, so no display is needed, no global
figure state accumulates and a figure is freed once it goes out of scope. PNGs
are written atomically: a crash never leaves a half-written file at ``path``.
"""

import contextlib
import math
import os
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from jobs.views.baselines import STRONGEST_PT_LABEL
from jobs.views.chart_styles import (
    ENVELOPE_OPACITY,
    ENVELOPE_STYLE,
    ENVELOPE_WIDTH,
    FRONT_COLOUR,
    SeriesStyle,
    series_styles,
)
from metrics.registry import LISTED

DPI = 110

# Sweep panels (Figure 13) from the registry: row key, axis label, log y axis, CI row key.
_SWEEP_PANELS = tuple(
    (m.field, m.label, m.log_axis, f"{m.field}_ci95" if m.ci_key else None)
    for m in LISTED if m.sweep_plot
)


def plot_sweep(rows: list[dict[str, Any]], path: Path, title: str,
               x_key: str = "ir_bounces_pct", x_label: str | None = None) -> Path:
    """Plot a sweep to a PNG at ``path``: by default an adaptive equal-bias sweep (NIRC
    paper, Figure 13) over the % indirect-radiance bounces; with ``x_key`` over another
    numeric row key (a parameter sweep's ``value``, named ``x_label``; a log axis when
    all values are positive and span more than a factor 10).

    Each row is one sweep point of one series, with keys ``series``, ``eps``,
    ``ir_bounces_pct``, ``ms_frame`` and one per panel (``mrse``, ``flip``,
    ``rbias2``, ``rvar``; ``mrse_ci95`` = [lo, hi] or None). Points with a missing or non-finite
    value are left out of that metric's panel, and on log panels points <= 0; a
    note on the panel counts each kind left out.
    """
    figure_13 = x_key == "ir_bounces_pct"
    xs_all = [_finite(row.get(x_key)) for row in rows]
    log_x = (not figure_13 and bool(xs_all) and all(x is not None and x > 0 for x in xs_all)
             and max(xs_all) > 10 * min(xs_all))  # type: ignore[type-var, operator]
    series = list(dict.fromkeys(str(row["series"]) for row in rows))
    styles = _styles((row.get("method"), str(row["series"])) for row in rows)
    nrows = math.ceil(len(_SWEEP_PANELS) / 2)
    figure, axes = new_figure(nrows, 2, title, figsize=(9.0, 3.5 * nrows))
    for ax in axes[len(_SWEEP_PANELS):]:  # an odd panel count leaves one cell empty
        figure.delaxes(ax)
    axes = axes[:len(_SWEEP_PANELS)]
    for ax, (key, label, log, ci_key) in zip(axes, _SWEEP_PANELS, strict=True):
        plotted, hidden, dropped = False, 0, 0
        for name in series:
            members = [row for row in rows if str(row["series"]) == name]
            pairs = ((row.get(x_key), row.get(key)) for row in members)
            xs, ys, below, missing = plottable(pairs, log=log)
            hidden, dropped = hidden + below, dropped + missing
            if xs:
                # Open markers: an equal-time series often coincides with its base
                # series (same N_c), which must stay visible.
                open_marker = "equal time" in name
                ax.plot(xs, ys, "s" if open_marker else "o", color=styles[name].colour,
                        linestyle=_linestyle(styles[name]), label=name,
                        markersize=6 if open_marker else 4,
                        fillstyle="none" if open_marker else "full")
                plotted = True
            if ci_key:
                draw_ci(ax, members, key, ci_key, styles[name].colour, x_key)
        ax.set_title(label)
        ax.set_xlabel("% indirect-radiance bounces" if figure_13 else str(x_label or x_key))
        ax.set_ylabel(label)
        if figure_13:
            ax.set_xlim(-3.0, 103.0)
            ax.set_xticks(range(0, 101, 25))
        elif log_x:
            ax.set_xscale("log")
        if log:
            ax.set_yscale("log")
        ax.grid(True, which="major", alpha=0.3)
        annotate_points(ax, plotted, hidden, dropped)

    handles = {}
    for ax in axes:
        for handle, name in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(name, handle)
    if handles:
        figure.legend(
            handles.values(), handles.keys(), loc="lower center", ncols=min(len(handles), 4)
        )
    return save_png(figure, path)


def plot_convergence(curves: dict[str, dict[str, Any]], path: Path, title: str) -> Path:
    """Plot MRSE over frames (NIRC paper, Figure 10) to a PNG at ``path``.

    ``curves[label]`` holds ``frame`` (frame indices), ``frame_mrse`` (MRSE of
    each single frame), optionally ``accumulated_mrse`` (MRSE of the running
    mean up to that frame), lists of equal length, and optionally ``method`` (its
    family's hue). Per-frame error is drawn solid, accumulated error dashed, in one
    colour per label; missing, non-finite
    and non-positive values are left out (the y axis is logarithmic) and counted in a
    note.
    """
    styles = _styles((curve.get("method"), label) for label, curve in curves.items())
    figure, (ax,) = new_figure(1, 1, title, figsize=(7.0, 4.5))
    plotted, hidden, dropped = False, 0, 0
    for label, curve in curves.items():
        for key, style, kind in (
            ("frame_mrse", "-", "per frame"),
            ("accumulated_mrse", "--", "accumulated"),
        ):
            if curve.get(key) is None:
                continue
            xs, ys, below, missing = plottable(zip(curve["frame"], curve[key], strict=True),
                                                log=True)
            hidden, dropped = hidden + below, dropped + missing
            if xs:
                ax.plot(xs, ys, style, color=styles[label].colour, label=f"{label} ({kind})")
                plotted = True
    ax.set_xlabel("frame")
    ax.set_ylabel("MRSE (relative, unitless)")
    ax.set_yscale("log")
    ax.grid(True, which="major", alpha=0.3)
    if plotted:
        ax.legend(fontsize="small")
    annotate_points(ax, plotted, hidden, dropped)
    return save_png(figure, path)


def plot_pareto(points: list[dict[str, Any]], key: str, label: str, path: Path,
                title: str, envelope: Sequence[Sequence[tuple[float, float]]] = ()) -> Path:
    """Plot error ``key`` against seconds per frame, log-log, to a PNG at ``path``.

    Each point (a jobs.pareto.pareto.ParetoPoint's ``model_dump``) has ``series``,
    ``seconds_per_frame``, ``seconds_spread`` = [min, max] (drawn as a horizontal
    bar), ``key``, ``front_<key>`` and ``loaded``. One line per series, through its
    points in the given (knob) order; the front is a black step line with ringed points;
    a point timed on a loaded machine is crossed in red. ``envelope``: the strongest PT's
    envelope as polylines of (seconds, error) (jobs/views/envelope.py), drawn as one
    series, wide and grey under the others (chart_styles.ENVELOPE_STYLE). Points without
    a finite value and those <= 0 (off the log axes) are left out and counted in a note.
    """
    series = list(dict.fromkeys(str(p["series"]) for p in points))
    styles = _styles((p.get("method"), str(p["series"])) for p in points)
    figure, (ax,) = new_figure(1, 1, title, figsize=(7.5, 5.0))
    plotted, hidden, dropped = False, 0, 0
    for name in series:
        members = [p for p in points if str(p["series"]) == name]
        drawn = [p for p in members if _positive(p.get(key)) and _positive(p["seconds_per_frame"])]
        dropped += dropped_points(p.get(key) for p in members)
        hidden += sum(1 for p in members if _finite(p.get(key)) is not None
                      and not _positive(p.get(key)))
        if not drawn:
            continue
        xs = [p["seconds_per_frame"] for p in drawn]
        ax.errorbar(xs, [p[key] for p in drawn], fmt="o", color=styles[name].colour,
                    linestyle=_linestyle(styles[name]), label=name,
                    markersize=5, capsize=2,
                    xerr=[[x - p["seconds_spread"][0] for x, p in zip(xs, drawn, strict=True)],
                          [p["seconds_spread"][1] - x for x, p in zip(xs, drawn, strict=True)]])
        plotted = True
    for k, line in enumerate(envelope):
        ax.plot([t for t, _ in line], [e for _, e in line], color=ENVELOPE_STYLE.colour,
                linestyle=_linestyle(ENVELOPE_STYLE), linewidth=ENVELOPE_WIDTH,
                alpha=ENVELOPE_OPACITY, solid_capstyle="round", zorder=0,
                label=STRONGEST_PT_LABEL if k == 0 else None)
    front = sorted((p["seconds_per_frame"], p[key]) for p in points
                   if p.get(f"front_{key}") and _positive(p.get(key)))
    if front:
        ax.step([x for x, _ in front], [y for _, y in front], where="post",
                color=FRONT_COLOUR, linewidth=1.5, zorder=1)
        ax.plot([x for x, _ in front], [y for _, y in front], "o", markersize=11,
                fillstyle="none", color=FRONT_COLOUR, label="Pareto front")
    loaded = [(p["seconds_per_frame"], p[key]) for p in points
              if p.get("loaded") and _positive(p.get(key)) and _positive(p["seconds_per_frame"])]
    if loaded:
        ax.plot([x for x, _ in loaded], [y for _, y in loaded], "x", markersize=10,
                color="red", zorder=3, label="timed on a loaded machine")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("seconds per frame (online training included)")
    ax.set_ylabel(label)
    ax.grid(True, which="both", alpha=0.3)
    if plotted:
        ax.legend(fontsize="small")
    annotate_points(ax, plotted, hidden, dropped)
    return save_png(figure, path)


def _positive(value: Any) -> bool:
    number = _finite(value)
    return number is not None and number > 0


def _finite(value: Any) -> float | None:
    """``value`` as a float, or None if it is None, NaN or infinite."""
    if value is None:
        return None
    number = float(value)
    return number if math.isfinite(number) else None


def dropped_points(values: Iterable[Any]) -> int:
    """How many of a series' ``values`` a plot leaves out as missing or not finite."""
    return sum(1 for value in values if _finite(value) is None)


def plottable(
    pairs: Iterable[tuple[Any, Any]], *, log: bool
) -> tuple[list[float], list[float], int, int]:
    """The (x, y) pairs that can be drawn, as x-sorted coordinate lists, then how many
    were left out: finite y <= 0 on a log axis (``log``), and pairs with a missing or
    non-finite coordinate, so the plot can say that some points are not shown.
    """
    points, hidden, dropped = [], 0, 0
    for raw_x, raw_y in pairs:
        x, y = _finite(raw_x), _finite(raw_y)
        if x is None or y is None:
            dropped += 1
            continue
        if log and y <= 0:
            hidden += 1
            continue
        points.append((x, y))
    points.sort()
    return [x for x, _ in points], [y for _, y in points], hidden, dropped


def draw_ci(ax: Axes, rows: list[dict[str, Any]], key: str, ci_key: str, colour: str,
             x_key: str = "ir_bounces_pct") -> None:
    """Error bars for the rows' ``ci_key`` intervals around ``key`` that fit on a log axis."""
    xs, ys, below, above = [], [], [], []
    for row in rows:
        x, y, interval = (
            _finite(row.get(x_key)),
            _finite(row.get(key)),
            row.get(ci_key),
        )
        if x is None or y is None or y <= 0 or interval is None:
            continue
        lo, hi = (_finite(bound) for bound in interval)
        if lo is None or hi is None or lo <= 0 or hi < lo:
            continue
        xs.append(x)
        ys.append(y)
        # A bootstrap interval need not contain its point estimate; clamp to it.
        below.append(max(y - lo, 0.0))
        above.append(max(hi - y, 0.0))
    if xs:
        ax.errorbar(xs, ys, yerr=[below, above], fmt="none", ecolor=colour, capsize=3, alpha=0.7)


def _styles(series: Iterable[tuple[str | None, str]]) -> dict[str, SeriesStyle]:
    """The chart styles (jobs/views/chart_styles.py) of (method or None, label) pairs;
    a label without a method is a family of its own."""
    return series_styles((method or label, label) for method, label in series)


def _linestyle(style: SeriesStyle) -> str | tuple[int, tuple[int, ...]]:
    return (0, style.dash) if style.dash else "-"


def new_figure(
    nrows: int, ncols: int, title: str, figsize: tuple[float, float]
) -> tuple[Figure, list[Axes]]:
    """A pyplot-free figure on an Agg canvas, its axes in row-major order, titled ``title``."""
    # Fixed margins: matplotlib's constrained layout cost ~0.8 s per figure here.
    figure = Figure(figsize=figsize, dpi=DPI)
    figure.subplots_adjust(left=0.1, right=0.97, top=0.9, bottom=0.15, hspace=0.4, wspace=0.3)
    FigureCanvasAgg(figure)
    figure.suptitle(title)
    return figure, list(figure.subplots(nrows, ncols, squeeze=False).ravel())


def annotate_points(ax: Axes, plotted: bool, hidden: int, dropped: int) -> None:
    """Say on the panel when it is empty, when points <= 0 were left off its log axis and
    when points were missing or not finite."""
    lines = [] if plotted else ["no data"]
    if hidden:
        lines.append(f"{hidden} point{'s' if hidden != 1 else ''} <= 0 not shown")
    if dropped:
        lines.append(f"{dropped} point{'s' if dropped != 1 else ''} missing or not finite, "
                     "not shown")
    if lines:
        ax.text(
            0.98,
            0.02,
            "\n".join(lines),
            transform=ax.transAxes,
            ha="right",
            va="bottom",
            fontsize="small",
            color="dimgray",
        )


def fit_margins(figure: Figure, pad_px: float = 4.0) -> None:
    """Widen the left margin until every panel's y label and tick labels lie inside the
    figure (wide log tick labels such as 4x10^-1 push a fixed margin's label out)."""
    renderer = figure.canvas.get_renderer()
    left = min((ax.get_tightbbox(renderer).x0 for ax in figure.axes), default=pad_px)
    if left < pad_px:
        shift = (pad_px - left) / figure.bbox.width
        figure.subplots_adjust(left=figure.subplotpars.left + shift)


def save_png(figure: Figure, path: Path) -> Path:
    """Write ``figure`` as a PNG to ``path`` atomically (temp file, then ``os.replace``),
    its margins fitted first (:func:`fit_margins`)."""
    fit_margins(figure)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, temp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as out:
            figure.savefig(out, format="png", dpi=DPI)
            out.flush()
            os.fsync(out.fileno())
        # mkstemp creates 0600; plots are read by other processes (report, service).
        os.chmod(temp_name, 0o644)
        os.replace(temp_name, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temp_name)
        raise
    return path
