"""Vega-Lite specs of the dashboard's charts, built with Altair.

The dashboard renders them with vega-embed (served by the app, no CDN); the same
dicts render to PNG files with vl-convert (:func:`chart_png`, e.g. ``render --out``'s
convergence.png), so a page and a file agree.

Every chart follows the same rules: one hue per method family, the same on every page,
shades and dashes for a family's configurations, every series its own colour
(jobs/views/chart_styles.py, given as explicit scales); the Pareto front black; the
strongest PT's envelope one series of its own, wide and grey, under its candidates; legends
beside or below the plot, never over it; axis titles with units; a log axis where the
values are positive and span more than a decade; wheel zoom and drag pan; a tooltip
with the run's parameters, and a click on a point opens its run (``href``). Values of
a log axis that are zero or negative (a noise-corrected rBias² below the noise floor)
are not drawn and the chart's subtitle counts them. Intervals are the ones the API
stores (log-scale, never below zero, none with fewer than 3 seeds): drawn, never
recomputed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import altair as alt
import vl_convert

from jobs.views.baselines import strongest_pt_of
from jobs.views.chart_groups import (
    FROZEN,
    KNOB_PARAMS,
    ONLINE,
    Group,
    config_label,
    curve_label,
    knob_order,
)
from jobs.views.chart_styles import (
    ENVELOPE_OPACITY,
    ENVELOPE_STYLE,
    ENVELOPE_WIDTH,
    FRONT_COLOUR,
    SeriesStyle,
    series_styles,
)
from jobs.views.envelope import baseline_curve, envelope_line
from jobs.views.front import pareto_front

WIDTH, HEIGHT = 520, 300
#: Where a chart's legend goes: below the plot, one entry a line, labels never cut.
LEGEND = alt.Legend(orient="bottom", direction="vertical", labelLimit=0, title=None)


def run_link(run_id: int) -> str:
    """The dashboard's page of a run (a hash route: the page never reloads)."""
    return f"#/run/{run_id}"


def params_text(params: Mapping[str, Any] | None) -> str:
    return ", ".join(f"{key}={value}" for key, value in sorted((params or {}).items())
                     if key not in ("spec", "scene_overrides", "calibration"))


def style_scales(series: Sequence[tuple[str, str]],
                 fixed: Mapping[str, SeriesStyle] | None = None) -> tuple[alt.Scale, alt.Scale]:
    """Explicit colour and dash scales of series labels from their (family, label) pairs
    (jobs/views/chart_styles.py) and the ``fixed`` styles of other series (the strongest
    PT's envelope); a chart gives both to one field, so one legend shows both."""
    styles = {**series_styles(series), **(fixed or {})}
    domain = sorted(styles)
    return (alt.Scale(domain=domain, range=[styles[d].colour for d in domain]),
            alt.Scale(domain=domain, range=[styles[d].vega_dash for d in domain]))


def family_of(row: Mapping[str, Any], label: str) -> str:
    """A row's method family: its method, or the label itself where it names none."""
    return str(row.get("method") or label)


def _spans_decades(values: Sequence[float]) -> bool:
    positive = [v for v in values if v > 0]
    return len(positive) == len(values) and bool(positive) and max(positive) > 10 * min(positive)


def value_scale(values: Sequence[float], log_axis: bool) -> alt.Scale:
    """Log where the metric is read on a log axis and its drawn values span a decade;
    else linear from zero (a lone value never makes an empty domain)."""
    if log_axis and _spans_decades(values):
        return alt.Scale(type="log")
    return alt.Scale(zero=True)


def axis_title(metric: Mapping[str, Any]) -> str:
    unit = metric.get("unit")
    return f"{metric['label']} ({unit})" if unit else f"{metric['label']} (relative, unitless)"


def _not_drawn(count: int) -> list[str]:
    return [f"{count} value{'s' if count != 1 else ''} ≤ 0 (below the noise floor) not drawn "
            "on the log axis"] if count else []


def _loaded(count: int) -> list[str]:
    return [f"{count} run{'s' if count != 1 else ''} timed on a loaded machine: drawn, on no "
            "front or envelope"] if count else []


def finish_chart(chart: alt.TopLevelMixin) -> dict[str, Any]:
    spec = chart.to_dict()
    spec.pop("$schema", None)       # a URL; the page names the mode instead
    return spec


def chart_png(spec: Mapping[str, Any], path: Path) -> Path:
    """``spec`` drawn to a PNG file by vl-convert: the library the dashboard draws it with."""
    path.write_bytes(vl_convert.vegalite_to_png(dict(spec), scale=2))
    return path


def chart_title(text: str, notes: Sequence[str]) -> alt.Title:
    return alt.Title(text, subtitle=list(notes), anchor="start") if notes \
        else alt.Title(text, anchor="start")


def envelope_rows(points: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The strongest PT's envelope over a chart's points (jobs/views/envelope.py): per
    strongest PT (``strongest``: its name, None for a point of no candidate) the lower
    envelope of its candidates' curves of two points or more, as rows (``curve`` its
    name, ``stretch`` the polyline between gaps, ``ms``, ``value``)."""
    by_name: dict[str, dict[str, list[Mapping[str, Any]]]] = {}
    for p in points:
        if p["strongest"] and p["value"] > 0 and not p["loaded"]:
            by_name.setdefault(p["strongest"], {}).setdefault(p["curve"], []).append(p)
    rows = []
    for name, curves in by_name.items():
        fitted = {curve: baseline_curve([p["ms"] for p in members], [p["value"] for p in members])
                  for curve, members in curves.items() if len(members) >= 2}
        rows += [{"curve": name, "stretch": f"{name} {k}", "ms": ms, "value": value}
                 for k, line in enumerate(envelope_line(fitted)) for ms, value in line]
    return rows


#: The time axis of an error-vs-time chart per protocol (jobs.views.chart_groups): a
#: run's frame time includes its online training; a sweep point's is the render alone
#: with its frozen, converged cache.
TIME_AXIS_TITLES = {ONLINE: "milliseconds per frame (online training included)",
                    FROZEN: "milliseconds per frame (render with a frozen cache)"}


def error_time_chart(group: Group, runs: Sequence[Mapping[str, Any]],
                     metric: Mapping[str, Any]) -> dict[str, Any] | None:
    """Error against milliseconds per frame of one group's runs: each run a point with
    its stored interval, each method's curve through its runs in knob order (spp, N_c,
    eps; jobs.views.chart_groups), the group's Pareto front in black. A run timed on a
    loaded machine is drawn (its tooltip says so) but is on no front and no envelope, as
    in the pareto study without ``--allow-loaded``. None when no run has the metric."""
    field, ci_field = metric["field"], metric.get("ci_field")
    usable = [r for r in runs if r.get(field) is not None and r.get("seconds_per_frame")]
    if not usable:
        return None
    log = metric["log_axis"]
    drawn = sorted((r for r in usable if r[field] > 0 or not log), key=knob_order)
    points = [{"run": r["id"], "ms": 1e3 * r["seconds_per_frame"], "value": r[field],
               "curve": curve_label(r), "family": r["method"], "order": i,
               "strongest": strongest_pt_of(r["method"], r.get("params") or {}, KNOB_PARAMS),
               "config": config_label(r), "params": params_text(r["params"]),
               "spp": r["spp"], "frames": r["frames"], "seeds": r["seeds"],
               "device": r["device_key"], "href": run_link(r["id"]),
               "loaded": bool(r.get("timing_flags")),
               "lo": (r.get(ci_field) or [None, None])[0] if ci_field else None,
               "hi": (r.get(ci_field) or [None, None])[1] if ci_field else None}
              for i, r in enumerate(drawn)]
    on_front = pareto_front([None if p["loaded"] else p["ms"] for p in points],
                            [p["value"] for p in points])
    front = sorted((p for p, on in zip(points, on_front, strict=True) if on),
                   key=lambda p: p["ms"])
    x = alt.X("ms:Q", title=TIME_AXIS_TITLES[group.protocol],
              scale=value_scale([p["ms"] for p in points], True))
    y_scale = value_scale([p["value"] for p in points], log)
    y = alt.Y("value:Q", title=axis_title(metric), scale=y_scale)
    envelope = envelope_rows(points)
    colours, dashes = style_scales([(p["family"], p["curve"]) for p in points],
                                   dict.fromkeys((r["curve"] for r in envelope), ENVELOPE_STYLE))
    tooltip = [alt.Tooltip("curve:N", title="series"),
               alt.Tooltip("config:N", title="configuration"), alt.Tooltip("run:Q", title="run"),
               alt.Tooltip("value:Q", title=metric["label"], format=".4g"),
               alt.Tooltip("lo:Q", title="95 % interval from", format=".4g"),
               alt.Tooltip("hi:Q", title="95 % interval to", format=".4g"),
               alt.Tooltip("ms:Q", title="ms per frame", format=".4g"),
               "spp:Q", "frames:Q", "seeds:Q", "device:N",
               alt.Tooltip("loaded:N", title="timed on a loaded machine"),
               alt.Tooltip("params:N", title="parameters")]
    data = alt.Data(values=points)
    zoom = alt.selection_interval(bind="scales")
    curves = alt.Chart(data).mark_line().encode(
        x=x, y=y, color=alt.Color("curve:N", scale=colours, legend=LEGEND),
        strokeDash=alt.StrokeDash("curve:N", scale=dashes, legend=LEGEND), order="order:Q")
    dots = alt.Chart(data).mark_point(filled=True, size=70).encode(
        x=x, y=y, color=alt.Color("curve:N", scale=colours, legend=None),
        tooltip=tooltip, href="href:N").add_params(zoom)
    bars = alt.Chart(data).transform_filter("datum.lo != null && datum.lo > 0").mark_rule().encode(
        x="ms:Q", y=alt.Y("lo:Q", scale=y_scale), y2="hi:Q",
        color=alt.Color("curve:N", scale=colours, legend=None))
    # A step line only: rings around the front's points would cover the runs' points
    # and take their hover and click.
    line = alt.Chart(alt.Data(values=front)).mark_line(
        interpolate="step-after", color=FRONT_COLOUR, strokeWidth=2.5, opacity=0.85,
    ).encode(x="ms:Q", y=alt.Y("value:Q", scale=y_scale))
    strongest = alt.Chart(alt.Data(values=envelope)).mark_line(
        strokeWidth=ENVELOPE_WIDTH, opacity=ENVELOPE_OPACITY,
    ).encode(x="ms:Q", y=alt.Y("value:Q", scale=y_scale), detail="stretch:N",
             color=alt.Color("curve:N", scale=colours, legend=LEGEND),
             strokeDash=alt.StrokeDash("curve:N", scale=dashes, legend=LEGEND))
    title = chart_title(f"{metric['label']} vs time — {group.title}",
                   ["black: Pareto front of this chart (spp, N_c, eps are points on a curve)",
                    *(["wide grey: the strongest PT, the best of its candidates at each time"]
                      if envelope else []),
                    *_loaded(sum(p["loaded"] for p in points)),
                    *_not_drawn(len(usable) - len(drawn))])
    layers = ([strongest] if envelope else []) + ([curves, line] if front else [curves])
    layers += [bars] if any(p["lo"] for p in points) else []
    return finish_chart(alt.layer(*layers, dots).properties(width=WIDTH, height=HEIGHT, title=title))


def history_chart(metric: Mapping[str, Any], setting: str, method: str,
                  series: Sequence[tuple[str, Sequence[Mapping[str, Any]]]]
                  ) -> dict[str, Any] | None:
    """A metric over commits of one setting: one line per configuration of ``method``
    (label, points of GET /api/v1/ci/history; shades and dashes of the method's hue),
    its stored intervals as bars; red rules
    at detected steps, grey dashed ones at version changes (never compared across).
    None when no commit has a value."""
    log = metric["log_axis"]
    rows, marks, below = [], [], 0
    for label, points in series:
        for p in points:
            commit = p["commit"][:7]
            if p.get("step"):
                marks.append({"commit": commit, "what": "step", "colour": "#d62728"})
            elif p.get("break_before"):
                marks.append({"commit": commit, "what": "version change", "colour": "#888"})
            if p["median"] is None:
                continue
            if log and p["median"] <= 0:
                below += 1
                continue
            ci = p.get("ci") or [None, None]
            rows.append({"commit": commit, "time": p["time"], "value": p["median"],
                         "lo": ci[0], "hi": ci[1], "n": p["n"], "config": label,
                         "family": method,
                         "runs": ", ".join(map(str, p["runs"])),
                         "href": run_link(p["runs"][-1])})
    if not rows:
        return None
    order = sorted({(r["time"], r["commit"]) for r in rows})
    commits = list(dict.fromkeys(commit for _, commit in order))
    x = alt.X("commit:N", sort=commits, title="commit, oldest to newest",
              axis=alt.Axis(labelAngle=-45))
    y_scale = value_scale([r["value"] for r in rows], log)
    colours, dashes = style_scales([(r["family"], r["config"]) for r in rows])
    data = alt.Data(values=rows)
    zoom = alt.selection_interval(bind="scales", encodings=["y"])
    line = alt.Chart(data).mark_line(point=alt.OverlayMarkDef(filled=True, size=50)).encode(
        x=x, y=alt.Y("value:Q", title=axis_title(metric), scale=y_scale),
        color=alt.Color("config:N", scale=colours, legend=LEGEND),
        strokeDash=alt.StrokeDash("config:N", scale=dashes, legend=LEGEND),
        tooltip=[alt.Tooltip("config:N", title="method"), "commit:N",
                 alt.Tooltip("value:Q", title=f"median {metric['label']}", format=".4g"),
                 alt.Tooltip("lo:Q", title="interval from", format=".4g"),
                 alt.Tooltip("hi:Q", title="interval to", format=".4g"),
                 alt.Tooltip("n:Q", title="values"), alt.Tooltip("runs:N", title="runs")],
        href="href:N").add_params(zoom)
    bars = alt.Chart(data).transform_filter("datum.lo != null && datum.lo > 0").mark_rule().encode(
        x=x, y=alt.Y("lo:Q", scale=y_scale), y2="hi:Q",
        color=alt.Color("config:N", scale=colours, legend=LEGEND))   # legend=None here drops it
    # One layer per kind with a fixed colour: a colour channel without a scale here would
    # merge with the series' colour scale and drop the legend.
    rules = [alt.Chart(alt.Data(values=[m for m in marks if m["colour"] == colour])).mark_rule(
        strokeWidth=1.5, strokeDash=[4, 3], color=colour).encode(
        x=x, tooltip=["what:N", "commit:N"]) for colour in dict.fromkeys(m["colour"] for m in marks)]
    title = chart_title(f"{metric['label']} over commits — {setting} ({metric['direction']} is better)",
                   ["red: detected step; grey: version change", *_not_drawn(below)])
    layers = [*rules, bars] if any(r["lo"] for r in rows) else rules
    return finish_chart(alt.layer(*layers, line).properties(width=WIDTH, height=HEIGHT, title=title))


def convergence_chart(run: Mapping[str, Any]) -> dict[str, Any] | None:
    """MRSE over the frames of a run, per seed (solid: the frame alone; dashed: the
    frames accumulated so far). None for a run of one frame: nothing converges."""
    rows = []
    for seed in run["per_seed"]:
        curve = seed["metrics"].get("convergence") or {}
        for kind, key in (("frame", "frame_mrse"), ("accumulated", "accumulated_mrse")):
            rows += [{"frame": i, "value": v, "seed": f"seed {seed['seed']}", "kind": kind,
                      "href": run_link(run["id"])}
                     for i, v in enumerate(curve.get(key) or []) if v is not None and v > 0]
    if run["frames"] < 2 or not rows:
        return None
    every = max(1, math.ceil(run["frames"] / 12))
    x = alt.X("frame:Q", title="frame", scale=alt.Scale(domain=[0, run["frames"] - 1], nice=False),
              axis=alt.Axis(values=list(range(0, run["frames"], every)), format="d"))
    y = alt.Y("value:Q", title="MRSE (relative, unitless)",
              scale=value_scale([r["value"] for r in rows], True))
    chart = alt.Chart(alt.Data(values=rows)).mark_line(point=True).encode(
        x=x, y=y, color=alt.Color("seed:N", legend=LEGEND),
        strokeDash=alt.StrokeDash("kind:N", scale=alt.Scale(domain=["frame", "accumulated"],
                                                            range=[[1, 0], [5, 3]]),
                                  legend=None),     # the subtitle says which is which
        tooltip=["seed:N", "kind:N", "frame:Q", alt.Tooltip("value:Q", title="MRSE", format=".4g")],
    ).add_params(alt.selection_interval(bind="scales"))
    return finish_chart(chart.properties(width=WIDTH, height=HEIGHT, title=chart_title(
        f"run {run['id']}: MRSE over frames — {config_label(run)}",
        ["solid: each frame; dashed: frames accumulated"])))


def sweep_chart(sweep_id: int, rows: Sequence[Mapping[str, Any]],
                metric: Mapping[str, Any], parameter: str | None = None
                ) -> dict[str, Any] | None:
    """A sweep's metric against the share of indirect-radiance bounces (an eps sweep, the
    NIRC paper's Fig. 13) or, for a sweep over ``parameter``, against its values; one
    line per series (a method's 'equal time' series a darker, dashed shade of its hue),
    each point linked to its run."""
    field, log = metric["field"], metric["log_axis"]
    usable = [r for r in rows if r.get(field) is not None]
    drawn = [r for r in usable if r[field] > 0 or not log]
    if not drawn:
        return None
    values = [{"pct": r["ir_bounces_pct"], "value": r[field], "config": r["series"],
               "family": family_of(r, r["series"]), "eps": r.get("eps"),
               "swept": r.get("value"), "run": r.get("id"),
               "href": run_link(r["id"]) if r.get("id") else None}
              for r in drawn]
    colours, dashes = style_scales([(v["family"], v["config"]) for v in values])
    if parameter is None:
        x = alt.X("pct:Q", title="indirect-radiance bounces (%)")
    elif all(isinstance(v["swept"], int | float) for v in values):
        x = alt.X("swept:Q", title=parameter,
                  scale=value_scale([v["swept"] for v in values], True))
    else:
        x = alt.X("swept:N", title=parameter)
    chart = alt.Chart(alt.Data(values=values)).mark_line(point=True).encode(
        x=x,
        y=alt.Y("value:Q", title=axis_title(metric),
                scale=value_scale([v["value"] for v in values], log)),
        color=alt.Color("config:N", scale=colours, legend=LEGEND),
        strokeDash=alt.StrokeDash("config:N", scale=dashes, legend=LEGEND),
        tooltip=[alt.Tooltip("config:N", title="series"),
                 alt.Tooltip("swept:N", title=parameter) if parameter is not None
                 else alt.Tooltip("eps:Q", title="eps"),
                 alt.Tooltip("pct:Q", title="% IR bounces", format=".3g"),
                 alt.Tooltip("value:Q", title=metric["label"], format=".4g"),
                 alt.Tooltip("run:Q", title="run")],
        href="href:N",
    ).add_params(alt.selection_interval(bind="scales"))
    return finish_chart(chart.properties(width=WIDTH, height=HEIGHT, title=chart_title(
        f"{metric['label']} — sweep {sweep_id}", _not_drawn(len(usable) - len(drawn)))))
