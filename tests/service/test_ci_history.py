"""GET /api/v1/ci/history over synthetic stored runs across commits: a planted step is
detected at its commit, a flat history has none, a version change is a break and never
a step, settings are separate series, filters and bad names are answered clearly."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import numpy as np
import pytest

from jobs.record.models import Run
from tests.jobs.factories import run_fields

START = datetime(2026, 1, 1, tzinfo=UTC)
URL = "/api/v1/ci/history?metric=mrse&scene=cornell-box&method=pt"


def store_history(store, levels, *, seed=0, versions=None, **overrides):
    """One run per commit ('c000001', ...) with 4 seeds of MRSE around ``levels[i]``."""
    rng = np.random.default_rng(seed)
    for i, level in enumerate(levels):
        values = level + rng.normal(0.0, 0.002, size=4)
        fields = run_fields(git_commit=f"c{i:06d}", created_at=START + timedelta(hours=i),
                            metrics={"mrse_mean": float(values.mean())},
                            estimator_version=(versions or {}).get(i, 1), **overrides)
        store.add_run(fields, [{"seed": s, "metrics": {"mrse": float(v)}, "timings": {}}
                               for s, v in enumerate(values)])


def steps(body):
    return [p["commit"] for s in body["series"] for p in s["points"] if p["step"]]


def test_a_planted_step_is_detected_at_its_commit(api_and_store):
    http, store = api_and_store
    store_history(store, [0.1] * 4 + [0.13] * 4)
    body = http.get(URL).json()
    (series,) = body["series"]
    points = series["points"]
    assert [p["commit"] for p in points] == [f"c{i:06d}" for i in range(8)]
    assert steps(body) == ["c000004"]
    assert points[4]["change"] == pytest.approx(0.03, abs=0.01)
    assert all(p["n"] == 4 and p["ci_level"] == pytest.approx(0.875) for p in points)
    assert all(p["ci"][0] <= p["median"] <= p["ci"][1] for p in points)
    assert body["test"].startswith("Welch") and body["alpha"] == 0.05


def test_a_flat_history_has_no_step(api_and_store):
    http, store = api_and_store
    store_history(store, [0.1] * 8, seed=1)
    body = http.get(URL).json()
    assert steps(body) == []
    assert all(p["p_value"] is not None for p in body["series"][0]["points"][1:])


def test_a_version_change_is_a_break_and_never_compared(api_and_store):
    http, store = api_and_store
    store_history(store, [0.1] * 4 + [0.13] * 4, versions={i: 2 for i in range(4, 8)})
    points = http.get(URL).json()["series"][0]["points"]
    assert points[4]["break_before"] == "estimator version 1 -> 2"
    assert points[4]["p_value"] is None and not points[4]["step"]
    assert points[4]["change"] is None
    assert not any(p["step"] for p in points)
    assert all(p["break_before"] is None for i, p in enumerate(points) if i != 4)


def test_settings_are_series_and_filters_apply(api_and_store):
    http, store = api_and_store
    store_history(store, [0.1] * 3)
    store_history(store, [0.2] * 3, width=32, height=32)
    body = http.get(URL).json()
    assert sorted(s["resolution"] for s in body["series"]) == [[32, 32], [64, 64]]
    body = http.get(URL + "&res=32").json()
    assert [s["resolution"] for s in body["series"]] == [[32, 32]]
    assert http.get(URL + "&device=elsewhere").json()["series"] == []
    assert len(http.get(URL + "&limit=2").json()["series"][0]["points"]) == 2


def test_dirty_commits_nonfinite_and_withheld_values_are_counted_not_pooled(api_and_store):
    http, store = api_and_store
    store.add_run(run_fields(git_commit="c0ffee1", metrics={"mrse_mean": 0.1}), [])
    store.add_run(run_fields(git_commit="c0ffee2", metrics={"mrse_mean": 0.2}),
                  [{"seed": 0, "metrics": {"mrse": 0.2}, "timings": {}},
                   {"seed": 1, "metrics": {"mrse": "Infinity"}, "timings": {}}])
    store.add_run(run_fields(git_commit="c0ffee3-dirty", metrics={"mrse_mean": 0.3}), [])
    store.add_run(run_fields(git_commit="unknown", metrics={"mrse_mean": 0.3}), [])
    store.add_run(run_fields(git_commit="c0ffee4", quality={"withheld": ["mrse"]},
                             metrics={"mrse_mean": 0.4}), [])
    body = http.get(URL).json()
    assert body["skipped_runs"] == 2
    points = body["series"][0]["points"]
    assert [p["commit"] for p in points] == ["c0ffee1", "c0ffee2", "c0ffee4"]
    assert (points[1]["n"], points[1]["nonfinite"], points[1]["median"]) == (1, 1, 0.2)
    assert points[2]["withheld"] == 1 and points[2]["median"] is None


@pytest.mark.skipif(not hasattr(Run, "git_branch"),
                    reason="runs record their branch from the ci-gate change on")
def test_the_branch_filter_keeps_the_runs_of_that_branch(api_and_store):
    http, store = api_and_store
    store.add_run(run_fields(git_commit="c0ffee1", git_branch="main",
                             metrics={"mrse_mean": 0.1}), [])
    store.add_run(run_fields(git_commit="c0ffee2", git_branch="topic",
                             metrics={"mrse_mean": 0.2}), [])
    store.add_run(run_fields(git_commit="c0ffee3", metrics={"mrse_mean": 0.3}), [])
    assert len(http.get(URL).json()["series"][0]["points"]) == 3
    main = http.get(URL + "&branch=main").json()["series"][0]["points"]
    assert [(p["commit"], p["branches"], p["median"]) for p in main] == [
        ("c0ffee1", ["main"], 0.1)]


@pytest.mark.parametrize("query, message", [
    ("metric=nope&scene=cornell-box&method=pt", "unknown metric 'nope'"),
    ("metric=mrse&scene=cornell-box&method=nope", "unknown method 'nope'"),
    ("metric=mrse&scene=nowhere&method=pt", "unknown scene 'nowhere'"),
])
def test_unknown_names_are_422_with_the_name(api_and_store, query, message):
    http, _ = api_and_store
    answer = http.get(f"/api/v1/ci/history?{query}")
    assert answer.status_code == 422
    error, = answer.json()["detail"]
    assert message in error["msg"] and error["loc"] == ["query", message.split()[1]]


@pytest.mark.parametrize("extra", ["&limit=0", "&limit=501", "&res=0x4", "&res=abc",
                                   "&alpha=1", "&branch="])
def test_bad_parameters_are_422(api_and_store, extra):
    http, _ = api_and_store
    assert http.get(URL + extra).status_code == 422


def test_metrics_without_seed_values_pool_the_runs(api_and_store):
    """rBias² is computed jointly over a run's seeds: one value per run, two runs a commit."""
    http, store = api_and_store
    for i in range(2):
        for value in (0.01, 0.03):
            store.add_run(run_fields(git_commit=f"b{i:06d}", metrics={"rbias2": value},
                                     created_at=START + timedelta(hours=i)), [])
    points = http.get(URL.replace("mrse", "rbias2")).json()["series"][0]["points"]
    assert [(p["n"], p["median"]) for p in points] == [(2, 0.02), (2, 0.02)]
    assert points[1]["p_value"] == pytest.approx(1.0) and not points[1]["step"]


def history_chart_lines(body, metric="mrse"):
    """{setting: {series: [medians over commits]}} of GET /api/v1/charts/history."""
    section = next(m for m in body["metrics"] if m["metric"] == metric)
    lines = {}
    for chart in section["charts"]:
        spec = chart["spec"]        # one data set of all layers is hoisted to the top
        rows = (spec["layer"][-1].get("data") or spec["data"])["values"]
        for row in sorted(rows, key=lambda row: row["time"]):
            lines.setdefault(chart["setting"], {}).setdefault(row["config"], []).append(
                round(row["value"], 2))
    return lines


def test_history_charts_group_by_setting_with_a_line_per_label_and_spp(api_and_store):
    """Runs at two spp of one setting are two lines of one chart (not a chart per spp),
    each its own medians; a sweep point's frozen cache is a chart of its own."""
    http, store = api_and_store
    store_history(store, [0.1] * 3)
    store_history(store, [0.05] * 3, seed=1, spp=4)
    store_history(store, [0.2] * 3, seed=2, params={"max_depth": 8,
                                                    "sweep": {"eps": 0.5, "series": "pt"}})
    lines = history_chart_lines(http.get("/api/v1/charts/history?scene=cornell-box"
                                         "&method=pt").json())
    online = "cornell-box, 64×64, 4 frames, online training, llvm:test-cpu"
    frozen = "cornell-box, 64×64, 4 frames, frozen cache, llvm:test-cpu"
    assert lines == {online: {"pt (max_depth 8), 1 spp": [0.1] * 3,
                              "pt (max_depth 8), 4 spp": [0.05] * 3},
                     frozen: {"pt (eps 0.5, max_depth 8), 1 spp": [0.2] * 3}}


def test_a_history_below_the_noise_floor_says_so_rather_than_none(api_and_store):
    """rBias² medians all at or below 0 cannot be drawn on its log axis: the answer
    counts them (the dashboard said 'No value of rBias²'); a history with no value
    counts none; MRSE's positive medians are drawn and none is counted."""
    http, store = api_and_store
    history = "/api/v1/charts/history?scene=cornell-box&method=pt"

    def section(metric: str) -> dict:
        return next(m for m in http.get(history).json()["metrics"] if m["metric"] == metric)

    assert section("rbias2")["below_noise_floor"] == section("rbias2")["medians"] == 0
    for i, value in enumerate((-0.001, -0.0002)):
        store.add_run(run_fields(git_commit=f"d{i:06d}", created_at=START + timedelta(hours=i),
                                 metrics={"rbias2": value, "mrse_mean": 0.1}),
                      [{"seed": s, "metrics": {"mrse": 0.1}, "timings": {}} for s in range(2)])
    rbias2, mrse = section("rbias2"), section("mrse")
    assert rbias2["charts"] == [] and rbias2["below_noise_floor"] == rbias2["medians"] == 2
    assert mrse["charts"] and mrse["below_noise_floor"] == 0
