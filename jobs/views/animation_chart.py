"""The dashboard's chart of animated runs (docs/animation.md): the seed-mean error of each
frame against its own reference with its interval band, one line per run (colours from
jobs/views/chart_styles.py), the change frames as labelled vertical rules; and the rows
of the recovery table beside it. Both read a run's stored ``metrics['animation']``
(jobs.protocol.animation): drawn, never recomputed.

A run is given as ``{"id", "method", "label", "animation"}`` (``label``: its method
configuration, jobs.views.chart_groups.config_label).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import altair as alt

from jobs.views.charts import (
    HEIGHT,
    LEGEND,
    WIDTH,
    chart_title,
    finish_chart,
    run_link,
    style_scales,
)

#: The colour of the change rules and their labels (no method's hue: chart_styles).
CHANGE_COLOUR = "#555555"


def change_marks(animation: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Each change inside the run's frames: its frame and what changed (a run stored
    before changes were labelled reads 'change at frame k')."""
    change_frames = animation["change_frames"]
    labels = animation.get("change_labels") or [f"change at frame {k}" for k in change_frames]
    curve = animation.get("frame_mrse") or {}
    count = len(curve.get("mean") or ())
    return [{"frame": frame, "label": label}
            for frame, label in zip(change_frames, labels, strict=True) if 0 < frame < count]


def series_labels(runs: Sequence[Mapping[str, Any]]) -> dict[int, str]:
    """Each run's line label: its configuration, with the run id where two runs share one."""
    labels = [run["label"] for run in runs]
    return {run["id"]: run["label"] if labels.count(run["label"]) == 1
            else f"{run['label']} (run {run['id']})" for run in runs}


def frame_rows(runs: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One row per run and frame: the seed mean and its interval (None with one seed)."""
    names = series_labels(runs)
    rows = []
    for run in runs:
        curve = run["animation"].get("frame_mrse")
        if not curve:
            continue
        low, high = curve["low"] or [None] * len(curve["mean"]), curve["high"] or \
            [None] * len(curve["mean"])
        rows += [{"frame": frame, "value": mean, "lo": lo, "hi": hi, "series": names[run["id"]],
                  "family": run["method"], "run": run["id"], "seeds": curve["seeds"],
                  "href": run_link(run["id"])}
                 for frame, (mean, lo, hi) in enumerate(zip(curve["mean"], low, high,
                                                            strict=True))]
    return rows


def frame_error_chart(runs: Sequence[Mapping[str, Any]]) -> dict[str, Any] | None:
    """Seed-mean MRSE per frame of ``runs`` (of one animated scene and setting), the
    Student-t interval of each frame as a band, the changes of the first run's animation
    as labelled rules. None when no run stored a per-frame error."""
    rows = frame_rows(runs)
    if not rows:
        return None
    marks = change_marks(runs[0]["animation"])
    colours, dashes = style_scales([(row["family"], row["series"]) for row in rows])
    frames = max(row["frame"] for row in rows) + 1
    x = alt.X("frame:Q", title="frame", scale=alt.Scale(domain=[0, frames - 1], nice=False),
              axis=alt.Axis(format="d", tickMinStep=1))
    y = alt.Y("value:Q", title="MRSE against the frame's reference (relative, unitless)",
              scale=alt.Scale(zero=True))
    data = alt.Data(values=rows)
    # The band's colour keeps the legend (legend=None on one layer drops the shared one).
    band = alt.Chart(data).transform_filter("datum.lo != null").mark_area(opacity=0.2).encode(
        x=x, y=alt.Y("lo:Q", stack=None), y2="hi:Q",
        color=alt.Color("series:N", scale=colours, legend=LEGEND))
    line = alt.Chart(data).mark_line(point=alt.OverlayMarkDef(filled=True, size=30)).encode(
        x=x, y=y, color=alt.Color("series:N", scale=colours, legend=LEGEND),
        strokeDash=alt.StrokeDash("series:N", scale=dashes, legend=LEGEND),
        tooltip=[alt.Tooltip("series:N", title="method"), alt.Tooltip("run:Q", title="run"),
                 "frame:Q", alt.Tooltip("value:Q", title="seed-mean MRSE", format=".4g"),
                 alt.Tooltip("lo:Q", title="95 % interval from", format=".4g"),
                 alt.Tooltip("hi:Q", title="95 % interval to", format=".4g"),
                 alt.Tooltip("seeds:Q", title="seeds")],
        href="href:N").add_params(alt.selection_interval(bind="scales", encodings=["y"]))
    changes = alt.Data(values=marks)
    rules = alt.Chart(changes).mark_rule(color=CHANGE_COLOUR, strokeDash=[4, 3],
                                         strokeWidth=1.5).encode(
        x="frame:Q", tooltip=[alt.Tooltip("frame:Q", title="change at frame"),
                              alt.Tooltip("label:N", title="what changed")])
    text = alt.Chart(changes).mark_text(color=CHANGE_COLOUR, align="left", baseline="top",
                                        dx=3, dy=2).encode(
        x="frame:Q", y=alt.value(0), text="label:N")
    layers = [band, line, rules, text] if marks else [band, line]
    title = chart_title("MRSE per frame (seed mean, 95 % band)",
                   ["dashed rules: the scene's changes"] if marks else [])
    return finish_chart(alt.layer(*layers).properties(width=WIDTH, height=HEIGHT, title=title))


def recovery_rows(runs: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per run and change: frames to recover with the bootstrap interval and the steady
    error, or why none was measured."""
    names = series_labels(runs)
    rows = []
    for run in runs:
        animation = run["animation"]
        labels = dict(zip(animation["change_frames"], animation.get("change_labels") or (),
                          strict=False))
        for found in animation.get("recovery") or ():
            frame = found["change_frame"]
            rows.append({"run": run["id"], "series": names[run["id"]], "change_frame": frame,
                         "label": labels.get(frame, f"change at frame {frame}"),
                         "frames": found.get("frames"), "low": found.get("low"),
                         "high": found.get("high"), "steady_error": found.get("steady_error"),
                         "within_window": found.get("within_window"),
                         "note": found.get("note")})
    return rows


def animated_view(runs: Sequence[Mapping[str, Any]]) -> dict[str, Any] | None:
    """The chart and the recovery rows of ``runs`` (None when none is animated)."""
    animated = [run for run in runs if run.get("animation")]
    if not animated:
        return None
    return {"chart": frame_error_chart(animated), "recoveries": recovery_rows(animated),
            "note": None if any(r["animation"].get("frame_mrse") for r in animated)
            else animated[0]["animation"].get("note", "no per-frame error stored")}
