"""A reproduced figure as a PNG: panels of quantities against the swept value, one line
per series with its 95 % intervals as error bars (the project's plotting helpers,
jobs/views/plots.py)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from jobs.reproduce.results import Point, Reproduction
from jobs.views.plots import annotate_points, draw_ci, new_figure, plottable, save_png


@dataclass(frozen=True)
class Panel:
    quantity: str              # a key of the reproduction's quantities
    title: str
    log_y: bool = True
    scene: str | None = None   # only this scene's points (None: all)


def plot_panels(reproduction: Reproduction, panels: list[Panel], path: Path, *,
                log_x: bool = True, columns: int = 2,
                marked: Callable[[Point], bool] = lambda _point: False) -> Path:
    """Draw ``panels`` (one line per series, x the points' swept value) to ``path``;
    points for which ``marked`` holds are drawn enlarged (e.g. a sample target)."""
    rows = math.ceil(len(panels) / columns)
    height = 3.6 * rows + 0.8   # inches: the panels and a band for the title above them
    figure, axes = new_figure(rows, columns, reproduction.title,
                               figsize=(4.6 * columns, height))
    figure.subplots_adjust(top=1.0 - 0.8 / height, bottom=0.6 / height)
    for ax in axes[len(panels):]:
        figure.delaxes(ax)
    for ax, panel in zip(axes, panels, strict=False):
        # A point without a swept value (a table's PT row) has no place on the x axis.
        points = [p for p in reproduction.points if p.x is not None
                  and (panel.scene is None or p.scene == panel.scene)]
        plotted, hidden, dropped = False, 0, 0
        for series in dict.fromkeys(p.series for p in points):
            members = [p for p in points if p.series == series and panel.quantity in p.values]
            rows_ = [{"x": p.x, "y": p.values[panel.quantity].value,
                      "ci": p.values[panel.quantity].ci95} for p in members]
            xs, ys, below, missing = plottable(((r["x"], r["y"]) for r in rows_),
                                                log=panel.log_y)
            hidden, dropped = hidden + below, dropped + missing
            if not xs:
                continue
            (line,) = ax.plot(xs, ys, "o-", markersize=3, label=series)
            plotted = True
            draw_ci(ax, rows_, "y", "ci", line.get_color(), x_key="x")
            big = [(p.x, p.values[panel.quantity].value) for p in members if marked(p)]
            big = [(x, y) for x, y in big if y is not None and (y > 0 or not panel.log_y)]
            if big:
                ax.plot(*zip(*big, strict=True), "D", markersize=8, color=line.get_color())
        ax.set_title(panel.title, fontsize="medium")
        ax.set_xlabel(reproduction.x_label)
        ax.set_ylabel(reproduction.quantities[panel.quantity])
        if log_x:
            ax.set_xscale("log")
        if panel.log_y:
            ax.set_yscale("log")
        ax.grid(True, which="major", alpha=0.3)
        if plotted:
            ax.legend(fontsize="x-small")
        annotate_points(ax, plotted, hidden, dropped)
    return save_png(figure, path)
