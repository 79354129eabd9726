"""Chart specs (jobs/protocol/charts.py) and which runs share a chart
(jobs/protocol/chart_groups.py): groups never mix settings, protocols or devices, a
configuration has one colour everywhere, axes and legends follow the rules."""

from __future__ import annotations

import json

from jobs.protocol.chart_groups import (
    FROZEN,
    ONLINE,
    PALETTE,
    colour_of,
    group_of,
    split_groups,
)
from jobs.protocol.charts import convergence_chart, error_time_chart, history_chart
from metrics.registry import BY_NAME


def run(run_id: int, **changes) -> dict:
    """A run as GET /api/v1/results lists it (the fields the charts read)."""
    return {"id": run_id, "method": "pt", "method_label": "pt", "params": {"rr_survival": 0.9},
            "resolution": [32, 32], "spp": 1, "frames": 4, "seeds": 3, "device_key": "cpu",
            "metric_version": 2, "estimator_version": 1, "current": True, "mrse": 0.1,
            "mrse_ci95": [0.08, 0.12], "flip": 0.3, "seconds_per_frame": 0.01, **changes}


def test_groups_split_every_setting_protocol_device_and_version():
    runs = [run(1), run(2, method_label="nirc (biased)"), run(3, resolution=[16, 16]),
            run(4, spp=2), run(5, frames=1), run(6, params={"sweep": {"eps": 0.5}}),
            run(7, device_key="gpu"), run(8, metric_version=1), run(9, current=False)]
    groups = split_groups(runs)
    assert len(groups) == 8
    assert [r["id"] for r in groups[group_of(runs[0])]] == [1, 2]   # two methods, one group
    assert group_of(runs[5]).protocol == FROZEN and group_of(runs[0]).protocol == ONLINE
    assert "16×16" in group_of(runs[2]).title and "frozen cache" in group_of(runs[5]).title


def test_a_configuration_has_one_colour_on_every_chart():
    assert colour_of("nirc (biased, bth, N_c 4)") == colour_of("nirc (biased, bth, N_c 4)")
    assert colour_of("pt") in PALETTE
    runs = [run(1), run(2, method_label="nirc (biased)", seconds_per_frame=0.02, mrse=0.05)]
    spec = error_time_chart(group_of(runs[0]), runs, BY_NAME["mrse"].to_json())
    scale = next(layer for layer in spec["layer"] if layer["mark"]["type"] == "point") \
        ["encoding"]["color"]["scale"]
    assert dict(zip(scale["domain"], scale["range"], strict=True)) == \
        {"pt": colour_of("pt"), "nirc (biased)": colour_of("nirc (biased)")}


def test_error_time_chart_has_units_links_tooltips_a_front_and_no_schema_url():
    runs = [run(1), run(2, method_label="nirc", seconds_per_frame=0.02, mrse=0.05),
            run(3, method_label="nrc", seconds_per_frame=0.03, mrse=0.2)]
    spec = error_time_chart(group_of(runs[0]), runs, BY_NAME["mrse"].to_json())
    text = json.dumps(spec)
    assert "http" not in text                                  # no $schema URL
    points = next(layer for layer in spec["layer"] if layer["mark"]["type"] == "point")
    assert points["encoding"]["href"]["field"] == "href"
    assert points["encoding"]["color"]["legend"]["orient"] == "bottom"
    assert {t["field"] for t in points["encoding"]["tooltip"]} >= {"config", "run", "params"}
    assert points["encoding"]["x"]["title"].startswith("milliseconds per frame")
    assert "MRSE" in points["encoding"]["y"]["title"]
    front = next(layer for layer in spec["layer"] if layer["mark"]["type"] == "line")
    assert [p["run"] for p in front["data"]["values"]] == [1, 2]   # nrc is dominated
    assert spec["params"][0]["bind"] == "scales"                 # wheel zoom, drag pan


def test_log_axis_only_where_values_span_decades_and_nonpositive_values_are_counted():
    rbias = BY_NAME["rbias2"].to_json()
    history = [("pt", [{"commit": f"c{i}", "time": f"2025-01-0{i + 1}", "median": m,
                        "ci": None, "n": 4, "runs": [i + 1]}
                       for i, m in enumerate([1e-4, 1e-2, -1e-5])])]
    spec = history_chart(rbias, "32×32, 1 spp, 4 frames", history)
    line = spec["layer"][-1]
    assert line["encoding"]["y"]["scale"]["type"] == "log"
    assert "1 value ≤ 0 (below the noise floor)" in " ".join(spec["title"]["subtitle"])
    flat = history_chart(rbias, "s", [("pt", history[0][1][:1])])
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
