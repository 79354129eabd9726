"""Charts of a stored reproduction of a paper's figure (jobs/reproduce/results.py, as
JSON): one Vega-Lite chart per quantity, our values with their 95 % intervals, one
colour per series, one panel per scene; the x axis is the figure's swept value, or the
series where it sweeps nothing."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import altair as alt

from jobs.views.charts import finish_chart


def _rows(reproduction: Mapping[str, Any], quantity: str) -> list[dict[str, Any]]:
    """The points with a finite value of ``quantity`` (none drawn without one)."""
    rows = []
    for point in reproduction["points"]:
        estimate = point["values"].get(quantity)
        if estimate is None or estimate.get("value") is None:
            continue
        lo, hi = estimate.get("ci95") or (estimate["value"], estimate["value"])
        rows.append({"scene": point["scene"], "series": point["series"], "x": point.get("x"),
                     "value": estimate["value"], "lo": lo, "hi": hi,
                     "paper": point.get("paper", {}).get(quantity)})
    return rows


def reproduction_charts(reproduction: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One chart per quantity of ``reproduction`` that has a value."""
    charts = []
    for quantity, label in reproduction["quantities"].items():
        rows = _rows(reproduction, quantity)
        if not rows:
            continue
        swept = all(row["x"] is not None for row in rows)
        x = (alt.X("x:Q", title=reproduction["x_label"]) if swept
             else alt.X("series:N", title="series"))
        base = alt.Chart(alt.Data(values=rows)).encode(
            x=x, color=alt.Color("series:N", title="series"),
            tooltip=["scene:N", "series:N", "x:Q", alt.Tooltip("value:Q", format=".3g"),
                     alt.Tooltip("lo:Q", format=".3g"), alt.Tooltip("hi:Q", format=".3g"),
                     alt.Tooltip("paper:Q", title="paper", format=".3g")])
        marks = base.mark_line(point=True) if swept else base.mark_point(filled=True)
        layers = [marks.encode(y=alt.Y("value:Q", title=label)),
                  base.mark_rule().encode(y="lo:Q", y2="hi:Q")]
        chart = alt.layer(*layers).properties(width=260, height=180).facet(
            column=alt.Column("scene:N", title=None))
        charts.append(finish_chart(chart.properties(
            title=alt.Title(f"{reproduction['figure']}: {label}", anchor="start"))))
    return charts
