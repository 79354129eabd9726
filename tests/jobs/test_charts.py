"""Chart specs (jobs/views/charts.py), which runs share a chart
(jobs/views/chart_groups.py) and their colours (jobs/views/chart_styles.py):
groups never mix settings, protocols or devices but hold every knob value of a method
as one curve, families have distinct hues, axes and legends follow the rules."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jobs.views import chart_styles
from jobs.views.chart_groups import FROZEN, ONLINE, curve_label, group_of, split_groups
from jobs.views.chart_styles import FAMILY_COLOURS, FRONT_COLOUR, series_styles
from jobs.views.charts import convergence_chart, error_time_chart, history_chart, sweep_chart
from metrics.registry import BY_NAME
from renderers.methods import METHODS


def run(run_id: int, **changes) -> dict:
    """A run as GET /api/v1/results lists it (the fields the charts read)."""
    return {"id": run_id, "scene": "cornell-box", "method": "pt", "method_label": "pt",
            "params": {"rr_survival": 0.9}, "resolution": [32, 32], "spp": 1, "frames": 4,
            "seeds": 3, "device_key": "cpu", "metric_version": 2, "estimator_version": 1,
            "current": True, "mrse": 0.1, "mrse_ci95": [0.08, 0.12], "flip": 0.3,
            "seconds_per_frame": 0.01, **changes}


def layer(spec: dict, mark: str, field: str | None = None) -> dict:
    """The layer of ``spec`` drawn with ``mark`` (whose x field is ``field`` if given)."""
    return next(lay for lay in spec["layer"] if lay["mark"]["type"] == mark
                and (field is None or lay["encoding"]["y"].get("field") == field))


def curve_layer(spec: dict) -> dict:
    """The layer of an error-vs-time chart drawing its curves (in knob order)."""
    return next(lay for lay in spec["layer"] if lay["mark"]["type"] == "line"
                and lay["encoding"].get("order", {}).get("field") == "order")


def chart_colours(spec: dict) -> dict[str, str]:
    """Each series of a chart and its colour, from the spec's explicit scale."""
    encoding = (spec.get("encoding") or layer(spec, "line")["encoding"])["color"]
    return dict(zip(encoding["scale"]["domain"], encoding["scale"]["range"], strict=True))


def assert_distinct_colours(colours: dict[str, str], families: dict[str, str]) -> None:
    """Every series its own colour, and two families never one hue (the family's first
    series carries its hue)."""
    assert len(set(colours.values())) == len(colours), colours
    hues = {families[label]: colour for label, colour in colours.items()
            if label == families[label] or colour in FAMILY_COLOURS.values()}
    assert len(set(hues.values())) == len(hues), hues


def test_groups_split_what_makes_runs_incomparable_but_not_spp_or_knobs():
    runs = [run(1), run(2, method_label="nirc (biased)"), run(3, resolution=[16, 16]),
            run(4, spp=2), run(5, frames=1), run(6, params={"sweep": {"eps": 0.5}}),
            run(7, device_key="gpu"), run(8, metric_version=1), run(9, current=False),
            run(10, scene="door"), run(11, method="nirc", params={"nc": [16]}, spp=1)]
    groups = split_groups(runs)
    assert len(groups) == 8
    # Two methods, two spp and two N_c: one group (spp and N_c are points on a curve).
    assert [r["id"] for r in groups[group_of(runs[0])]] == [1, 2, 4, 11]
    assert group_of(runs[5]).protocol == FROZEN and group_of(runs[0]).protocol == ONLINE
    assert "16×16" in group_of(runs[2]).title and "frozen cache" in group_of(runs[5]).title
    assert "spp" not in group_of(runs[0]).title


def test_a_method_is_one_curve_over_its_knobs_and_configurations_are_curves_of_their_own():
    nirc = [run(i, method="nirc", params={"nc": [nc]}) for i, nc in enumerate((1, 4, 16))]
    assert {curve_label(r) for r in nirc} == {"nirc"}
    assert curve_label(run(5, method="nirc", params={"nc": [3, 1, 1],
                                                     "estimator": "unbiased"})) == \
        "nirc (unbiased)"
    eps = [run(i, method="nirc", params={"sweep": {"series": "nirc", "eps": e}})
           for i, e in enumerate((0.1, 0.5))]
    assert {curve_label(r) for r in eps} == {"nirc"}
    equal_time = run(7, method="nirc", params={"nc": [8], "sweep": {
        "series": "nirc-equal-time", "eps": 0.5}})
    assert curve_label(equal_time) == "nirc equal time"
    # The paper's PT and PT with throughput roulette are two curves.
    assert curve_label(run(8, params={})) == "pt"
    assert curve_label(run(9, params={"rr_mode": "throughput"})) == "pt (rr_mode throughput)"


def test_pareto_chart_draws_each_curve_over_spp_with_a_black_front():
    runs = [run(i, spp=spp, seconds_per_frame=0.01 * spp, mrse=0.4 / spp, params={})
            for i, spp in enumerate((1, 2, 4, 8, 16), start=1)]
    runs += [run(10 + i, spp=spp, seconds_per_frame=0.006 * spp, mrse=0.5 / spp,
                 params={"rr_mode": "throughput"}) for i, spp in enumerate((1, 4, 16))]
    runs += [run(20 + i, method="nirc", params={"nc": [nc]}, seconds_per_frame=0.02 + 0.001 * nc,
                 mrse=0.05 + 0.1 / nc) for i, nc in enumerate((1, 4, 16))]
    (group, members), = split_groups(runs).items()
    spec = error_time_chart(group, members, BY_NAME["mrse"].to_json())
    curves = curve_layer(spec)
    points = curves["data"]["values"]
    pt = sorted((p for p in points if p["curve"] == "pt"), key=lambda p: p["order"])
    assert [p["spp"] for p in pt] == [1, 2, 4, 8, 16]
    assert set(chart_colours(spec)) == {"pt", "pt (rr_mode throughput)", "nirc",
                                        "strongest PT"}
    assert_distinct_colours(chart_colours(spec), {"pt": "pt", "pt (rr_mode throughput)": "pt",
                                                  "nirc": "nirc", "strongest PT": "strongest PT"})
    front = next(lay for lay in spec["layer"] if lay["mark"].get("color") == FRONT_COLOUR)
    assert front["mark"]["interpolate"] == "step-after"
    assert FRONT_COLOUR not in chart_colours(spec).values()
    assert {p["run"] for p in front["data"]["values"]} >= {10, 20}   # cheapest, nirc N_c 1


def envelope_of(spec: dict) -> tuple[dict, list[dict]]:
    """An error-vs-time chart's strongest-PT layer and its rows."""
    found = next(lay for lay in spec["layer"] if lay["mark"].get("strokeWidth")
                 == chart_styles.ENVELOPE_WIDTH)
    return found, found["data"]["values"]


def test_the_strongest_pt_is_one_grey_series_the_least_error_of_its_candidates():
    """Two candidates (throughput roulette) whose curves cross, and the paper's PT below
    both (no candidate): the envelope is the lower candidate at every time, log-log
    between the runs, and nothing of the paper's PT."""
    def curve(first_id, method, points, **params):
        return [run(first_id + i, method=method, spp=2 ** i, seconds_per_frame=ms / 1e3,
                    mrse=error, params=params) for i, (ms, error) in enumerate(points)]
    pt = [(1.0, 0.1), (4.0, 0.02)]
    power = [(1.0, 0.05), (1.5, 0.047), (4.0, 0.04)]
    runs = (curve(1, "pt", pt, rr_mode="throughput")
            + curve(10, "pt-power", power, rr_mode="throughput")
            + curve(20, "pt", [(1.0, 0.01), (4.0, 0.001)]))
    (group, members), = split_groups(runs).items()
    spec = error_time_chart(group, members, BY_NAME["mrse"].to_json())
    envelope, rows = envelope_of(spec)
    assert {r["curve"] for r in rows} == {"strongest PT"}
    assert chart_colours(spec)["strongest PT"] == chart_styles.ENVELOPE_STYLE.colour
    assert envelope["encoding"]["strokeDash"]["scale"] == curve_layer(spec)["encoding"][
        "strokeDash"]["scale"]                              # one legend entry for it
    assert "strongest PT" in " ".join(spec["title"]["subtitle"])

    def loglog(points, ms):
        return np.exp(np.interp(np.log(ms), *np.log(np.array(points)).T))

    ms = [r["ms"] for r in rows]
    assert ms == sorted(ms) and ms[0] == 1.0 and ms[-1] == 4.0
    for r in rows:
        assert r["value"] == pytest.approx(min(loglog(pt, r["ms"]), loglog(power, r["ms"])))
    assert {1.5} < set(ms)                     # the lower candidate's own point is a vertex
    # Planted: the paper's PT taken as a candidate would be the envelope (it is lower).
    assert all(r["value"] > loglog([(1.0, 0.01), (4.0, 0.001)], r["ms"]) for r in rows)
    # No candidate curve of two points: no envelope, no legend entry.
    alone = error_time_chart(group, runs[:1] + runs[4:], BY_NAME["mrse"].to_json())
    assert "strongest PT" not in chart_colours(alone)
    assert not any(lay["mark"].get("strokeWidth") == chart_styles.ENVELOPE_WIDTH
                   for lay in alone["layer"])


def test_every_registered_method_has_its_own_hue_none_black_or_grey():
    assert set(FAMILY_COLOURS) == set(METHODS)
    assert len(set(FAMILY_COLOURS.values())) == len(FAMILY_COLOURS)
    for hue in FAMILY_COLOURS.values():
        red, green, blue = (int(hue[i:i + 2], 16) for i in (1, 3, 5))
        assert max(red, green, blue) - min(red, green, blue) > 24, hue   # not grey


def test_colours_are_distinct_within_a_chart_and_a_shared_hue_is_caught(monkeypatch):
    families = {"NIRC": "nirc", "NIRC equal time": "nirc", "NRC": "nrc", "other": "other"}
    rows = [{"series": s, "method": m if m != "other" else None, "ir_bounces_pct": pct,
             "mrse": 0.1, "flip": 0.2, "eps": 0.5, "id": 1}
            for s, m in families.items() for pct in (10.0, 50.0)]
    families["other"] = "other"
    spec = sweep_chart(1, rows, BY_NAME["mrse"].to_json())
    colours = chart_colours(spec)
    assert_distinct_colours(colours, families)
    assert colours["NIRC"] == FAMILY_COLOURS["nirc"] and colours["NRC"] == FAMILY_COLOURS["nrc"]
    # N_c 8 and N_c 16 of one method: two shades, two dashes.
    styles = series_styles([("nirc", "nirc (N_c 8)"), ("nirc", "nirc (N_c 16)")])
    assert styles["nirc (N_c 8)"] != styles["nirc (N_c 16)"]
    assert styles["nirc (N_c 8)"].colour != styles["nirc (N_c 16)"].colour
    # Planted: NIRC and NRC mapped to one colour (as a hashed palette did) is rejected.
    monkeypatch.setitem(chart_styles.FAMILY_COLOURS, "nrc", FAMILY_COLOURS["nirc"])
    with pytest.raises(AssertionError):
        assert_distinct_colours(chart_colours(sweep_chart(1, rows, BY_NAME["mrse"].to_json())),
                                families)


def test_error_time_chart_has_units_links_tooltips_a_front_and_no_schema_url():
    runs = [run(1), run(2, method="nirc", method_label="nirc", seconds_per_frame=0.02,
                        mrse=0.05),
            run(3, method="nrc", method_label="nrc", seconds_per_frame=0.03, mrse=0.2)]
    spec = error_time_chart(group_of(runs[0]), runs, BY_NAME["mrse"].to_json())
    text = json.dumps(spec)
    assert "http" not in text                                  # no $schema URL
    points = layer(spec, "point")
    assert points["encoding"]["href"]["field"] == "href"
    assert layer(spec, "line", "value")["encoding"]["color"]["legend"]["orient"] == "bottom"
    assert {t["field"] for t in points["encoding"]["tooltip"]} >= {"curve", "config", "run",
                                                                   "params"}
    assert points["encoding"]["x"]["title"].startswith("milliseconds per frame")
    assert "MRSE" in points["encoding"]["y"]["title"]
    front = next(lay for lay in spec["layer"] if lay["mark"].get("color") == FRONT_COLOUR)
    assert [p["run"] for p in front["data"]["values"]] == [1, 2]   # nrc is dominated
    assert spec["params"][0]["bind"] == "scales"                 # wheel zoom, drag pan


def test_the_time_axis_says_what_a_frame_time_holds():
    """An online-training group's frame times include the caches' training; a sweep
    point's (frozen cache) are the render alone, and its chart says so (it read
    'online training included' before)."""
    online = [run(1), run(2, method="nirc", method_label="nirc", mrse=0.05)]
    frozen = [run(k, method="nirc", method_label=f"nirc (adaptive, eps {eps})",
                  params={"sweep": {"eps": eps}}, mrse=0.1 * eps)
              for k, eps in ((3, 0.1), (4, 0.5))]
    titles = {}
    for runs in (online, frozen):
        group = group_of(runs[0])
        spec = error_time_chart(group, runs, BY_NAME["mrse"].to_json())
        titles[group.protocol] = layer(spec, "point")["encoding"]["x"]["title"]
    assert titles[ONLINE] == "milliseconds per frame (online training included)"
    assert titles[FROZEN].startswith("milliseconds per frame") \
        and "frozen cache" in titles[FROZEN] and "training" not in titles[FROZEN]


def test_log_axis_only_where_values_span_decades_and_nonpositive_values_are_counted():
    rbias = BY_NAME["rbias2"].to_json()
    history = [("pt", [{"commit": f"c{i}", "time": f"2025-01-0{i + 1}", "median": m,
                        "ci": None, "n": 4, "runs": [i + 1]}
                       for i, m in enumerate([1e-4, 1e-2, -1e-5])])]
    spec = history_chart(rbias, "32×32, 1 spp, 4 frames", "pt", history)
    line = spec["layer"][-1]
    assert line["encoding"]["y"]["scale"]["type"] == "log"
    assert "1 value ≤ 0 (below the noise floor)" in " ".join(spec["title"]["subtitle"])
    flat = history_chart(rbias, "s", "pt", [("pt", history[0][1][:1])])
    assert flat["layer"][-1]["encoding"]["y"]["scale"] == {"zero": True}


def test_convergence_has_integer_frame_ticks_and_none_for_one_frame():
    per_seed = [{"seed": 0, "metrics": {"convergence": {"frame_mrse": [0.4, 0.3, 0.2],
                                                        "accumulated_mrse": [0.4, 0.2, 0.1]}}}]
    spec = convergence_chart({**run(1), "frames": 3, "per_seed": per_seed})
    assert spec["encoding"]["x"]["axis"]["values"] == [0, 1, 2]
    assert spec["encoding"]["x"]["axis"]["format"] == "d"
    one = {**run(1), "frames": 1,
           "per_seed": [{"seed": 0, "metrics": {"convergence": {"frame_mrse": [0.4],
                                                                "accumulated_mrse": [0.4]}}}]}
    assert convergence_chart(one) is None


def test_a_run_timed_on_a_loaded_machine_is_drawn_on_no_front_or_envelope():
    """As pareto's rule without --allow-loaded: a loaded run that would dominate every PT
    run (fastest, less error) is drawn and says so, but is neither on the front nor part
    of the strongest PT's envelope; the same run unflagged is on both."""
    def candidate(run_id, method, spp, ms, error, **changes):
        return run(run_id, method=method, spp=spp, seconds_per_frame=ms / 1e3, mrse=error,
                   params={"rr_mode": "throughput"}, **changes)

    flags = {"timing_flags": ["loaded: load average 6.1 on 2 cores"]}
    pt = [candidate(1, "pt", 1, 2.0, 0.1), candidate(2, "pt", 2, 4.0, 0.05),
          candidate(3, "pt", 4, 8.0, 0.02)]
    power = candidate(11, "pt-power", 2, 9.0, 0.0009)

    def chart(fastest: dict) -> dict:
        (group, members), = split_groups([*pt, fastest, power]).items()
        return error_time_chart(group, members, BY_NAME["mrse"].to_json())

    def front_runs(spec: dict) -> set[int]:
        front = next(lay for lay in spec["layer"] if lay["mark"].get("color") == FRONT_COLOUR)
        return {p["run"] for p in front["data"]["values"]}

    spec = chart(candidate(10, "pt-power", 1, 0.5, 0.001, **flags))
    assert front_runs(spec) == {1, 2, 3, 11}
    assert min(r["ms"] for r in envelope_of(spec)[1]) == 2.0      # pt's own, from 2 ms
    assert {p["run"]: p["loaded"] for p in curve_layer(spec)["data"]["values"]}[10] is True
    assert "1 run timed on a loaded machine" in " ".join(spec["title"]["subtitle"])
    # Planted: the same run without its flag dominates pt's runs and starts the envelope.
    unflagged = chart(candidate(10, "pt-power", 1, 0.5, 0.001))
    assert front_runs(unflagged) == {10, 11}
    assert min(r["ms"] for r in envelope_of(unflagged)[1]) == 0.5
