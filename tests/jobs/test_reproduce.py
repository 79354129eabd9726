"""``nirc-bench reproduce`` (jobs/reproduce): the registry lists its figures, a figure runs
end to end at a tiny budget and writes its PNG and a table with 95 % intervals, reading
its points back from the store when run again; a bad figure name exits 2 with the
choices; the paper's data file parses and every row states its page."""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any
from unittest import mock

import pytest
from typer.testing import CliRunner

from jobs.record.config import Settings
from jobs.reproduce import measure, vt_fig7, vt_fig9, vt_table1
from jobs.reproduce.papers import PaperValue, paper_data
from jobs.reproduce.registry import MODES, Budget, Context, figures
from jobs.reproduce.results import Estimate, Point, Reproduction
from jobs.reproduce.run import reproduce
from jobs.sweeps import sweep as sweep_module
from jobs.views import plots
from service.cli import app, main

#: One threshold at 8x8, K = 3 (the fewest seeds that give an interval), F = 2 (the fewest
#: frames that give one frame's variance about its cache): the end-to-end test renders
#: one point (3 renders, the most of this file's time); the stubbed tests below draw
#: several per series.
TINY = Budget(resolution=8, seeds=3, frames=2, ref_spp=16, grid_preset="cpu", why="test",
              values=(10.0,))


def test_list_names_every_registered_figure() -> None:
    result = CliRunner().invoke(app, ["reproduce", "list", "--json"])
    assert result.exit_code == 0, result.output
    listed = {row["command"] for row in json.loads(result.output) if row["status"] == "runs"}
    assert listed == {f"nirc-bench reproduce {f.paper} {f.key}" for f in figures()}
    assert {"fig7", "fig9", "table1"} <= {f.key for f in figures()}


def assert_intervals(reproduction: Reproduction) -> None:
    """Every drawn quantity of every point has a finite value inside its 95 % interval."""
    for point in reproduction.points:
        for key in reproduction.quantities:
            estimate = point.values[key]
            assert estimate.value is not None and estimate.ci95 is not None, (point, key)
            low, high = estimate.ci95
            assert low <= estimate.value <= high, (point, key)


def _recorded_sweep_plot(drawn: list[Path]) -> Any:
    """A stand-in for the sweep's own plot (not this command's figure; tested with the
    sweep) that records the files it is asked for and writes them empty."""
    def plot_sweep(_rows: object, path: Path, *_args: object, **_kwargs: object) -> Path:
        drawn.append(path)
        path.write_bytes(b"")
        return path

    return plot_sweep


def test_fig7_runs_end_to_end_and_reuses_its_points(sqlite_store, data_folder: Path,
                                                     tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(vt_fig7, "SURVIVALS", (0.6,))
    monkeypatch.setattr(measure, "PREFILL_FRAMES", 1)
    drawn: list[Path] = []
    monkeypatch.setattr(plots, "plot_sweep", _recorded_sweep_plot(drawn))
    settings = Settings(data_dir=data_folder)
    result, paths = reproduce("vt", "fig7", "quick", tmp_path / "out", sqlite_store, settings,
                              budget=TINY)
    assert paths["figure"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # The figure draws its own plot: the sweep it measures through draws none.
    assert drawn == []
    assert {path.suffix for path in (data_folder / "sweeps").rglob("*.*")} == {".json"}
    stored = Reproduction.model_validate_json(paths["json"].read_text())
    assert [p.x for p in stored.points] == [10.0]
    assert_intervals(stored)
    assert stored.work == {"points_rendered": 1, "points_reused": 0}
    assert stored.settings["runs' grid presets"] == ["cpu"]
    assert stored.claims and all(c["page"] >= 1 for c in stored.claims)
    table = paths["markdown"].read_text()
    assert "| door | survival 60% | 10 |" in table and "Intervals:" in table
    # A run's estimates without intervals (planted) are caught by the same check.
    stripped = result.model_copy(update={"points": [
        p.model_copy(update={"values": {k: Estimate(value=e.value) for k, e in p.values.items()}})
        for p in result.points]})
    with pytest.raises(AssertionError):
        assert_intervals(stripped)
    # Planted: a sweep that drops the caller's plots=False (its default: its own plot).
    run_sweep = sweep_module.run_sweep
    monkeypatch.setattr(sweep_module, "run_sweep",
                        lambda *args, plots=False, **kwargs: run_sweep(*args, **kwargs))
    again, _paths = reproduce("vt", "fig7", "quick", tmp_path / "again", sqlite_store,
                              settings, budget=TINY)
    assert [path.name for path in drawn] == ["sweep_parameter.png"]
    assert again.work == {"points_rendered": 0, "points_reused": 1}
    assert [p.run_id for p in again.points] == [p.run_id for p in result.points]


def _sweep_calls(module: Any, mode: str, monkeypatch: pytest.MonkeyPatch
                 ) -> list[dict[str, Any]]:
    """What ``module``'s figure asks the sweep for at ``mode``'s budget (stubbed)."""
    calls: list[dict[str, Any]] = []

    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[Any],
              params: dict[str, Any], max_depth: int = -1) -> list[tuple[Any, Any]]:
        calls.append({"scene": scene, "method": method, "parameter": parameter,
                      "values": list(values), "params": params, "max_depth": max_depth,
                      "budget": replace(ctx.budget, values=())})
        return [_stored(float(v), ctx.budget.grid_preset) for v in values]

    monkeypatch.setattr(module, "sweep", sweep)
    module.FIGURE.measure(Context(module.FIGURE.budgets[mode], None, None))
    return calls


@pytest.mark.parametrize("mode", MODES)
def test_table1s_var_bound_rows_on_door_are_fig7s_points(
        mode: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Table 1's absolute var-bound rows on door ask the sweep for Fig. 7's points (the
    same parameters, depth limit and budget), so that ``--all`` renders them once.
    Planted: Table 1 at another survival (90 %, its own before) shares none."""
    fig7 = _sweep_calls(vt_fig7, mode, monkeypatch)

    def shared() -> tuple[int, int]:
        rows = [c for c in _sweep_calls(vt_table1, mode, monkeypatch)
                if c["scene"] == "door" and c["params"].get("termination") == "var-bound"
                and not c["params"]["termination_params"]["relative"]]
        alike = [v for c in rows for v in c["values"] if any(
            {**f, "values": None} == {**c, "values": None} and v in f["values"]
            for f in fig7)]
        return sum(len(c["values"]) for c in rows), len(alike)

    rows, alike = shared()
    assert rows == 3 and alike == 3
    monkeypatch.setattr(vt_table1, "RR_SURVIVAL", 0.9)
    assert shared() == (3, 0)


def test_a_bad_figure_name_exits_2_naming_the_choices(capsys, data_folder: Path) -> None:
    argv = ["nirc-bench", "reproduce", "vt", "fig8", "--data-dir", str(data_folder)]
    with mock.patch.object(sys, "argv", argv), pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("nirc-bench: error: unknown figure 'fig8'") and "table1" in err
    assert err.count("\n") == 1


def test_the_papers_data_file_parses_and_every_row_has_a_page() -> None:
    data = paper_data("vt")
    assert data.values and data.claims
    assert all(row.page >= 1 and row.quote for row in [*data.values, *data.claims])
    # Every row of Table 1 we render has the paper's path length beside it.
    values, _claims = data.of("table1")
    lengths = {(v.scene, v.series, v.setting) for v in values if v.quantity == "path_length"}
    wanted = {(theirs, policy, setting) for theirs in vt_table1.SCENES.values()
              for policy, _name, settings, _fixed, _symbol in vt_table1.POLICIES
              for setting in settings}
    assert wanted <= lengths
    row = data.values[0].model_dump()
    del row["page"]
    with pytest.raises(ValueError, match="page"):
        PaperValue.model_validate(row)   # a row without its page is refused


def _point(series: str, ours: float, theirs: float) -> Point:
    return Point(scene="door", series=series, values={"path_length": Estimate(value=ours)},
                 paper={"path_length": theirs})


def test_policy_order_counts_pairs_ordered_alike() -> None:
    alike = [_point("a", 1.0, 1.0), _point("b", 2.0, 4.0), _point("c", 3.0, 3.0)]
    order, agree, total = vt_table1.policy_order(alike, "door", "path_length")
    assert (order, agree, total) == (["a", "c", "b"], 2, 3)
    reversed_ = [_point("a", 3.0, 1.0), _point("b", 2.0, 2.0), _point("c", 1.0, 3.0)]
    assert vt_table1.policy_order(reversed_, "door", "path_length")[1:] == (0, 3)


def _stored(value: float, preset: str) -> tuple[Any, Any]:
    """A sweep row and its run as the store gives them, with seeded-looking numbers."""
    note = {f"{k}_ci_note": "t" for k in ("rvar", "rbias2", "mrse")}
    row = SimpleNamespace(id=int(value * 1000), value=value, rvar=0.2, rvar_ci95=[0.1, 0.4],
                          rbias2=0.05, rbias2_ci95=[0.01, 0.09], mrse=0.3,
                          mrse_ci95=[0.2, 0.5], kernel_breakdown_ms={"render": 3.0,
                                                                     "propagation": 9.0},
                          **note)
    seeds = [SimpleNamespace(metrics={"path_stats": {"weighted_length": length},
                                      "method_stats": {"caches": {"cache": {"preset": preset}}}})
             for length in (2.0, 2.5, 3.0)]
    run = SimpleNamespace(metrics={"rvar_per_cache": [0.7, 0.8, 0.9]},
                          path_stats={"weighted_length": 2.5}, seed_results=seeds)
    return row, run


@pytest.mark.parametrize("module", [vt_fig7, vt_fig9, vt_table1])
def test_every_figure_measures_writes_and_draws_from_stored_points(
        module: Any, monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Each registered figure asks the sweep for its points with the budget's grid preset
    and writes a table with intervals and its PNG (the sweep stubbed: its points are
    rendered in the end-to-end test above)."""
    calls: list[dict[str, Any]] = []

    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[Any],
              params: dict[str, Any], max_depth: int = -1) -> list[tuple[Any, Any]]:
        calls.append({"method": method, "params": params, "max_depth": max_depth})
        return [_stored(float(v), ctx.budget.grid_preset) for v in values]

    monkeypatch.setattr(module, "sweep", sweep)
    budget = replace(TINY, values=(1.0, 10.0))   # sample targets on Fig. 9's N axis
    result, paths = reproduce("vt", module.FIGURE.key, "quick", tmp_path, None, None,
                              budget=budget)
    assert paths["figure"].read_bytes()[:4] == b"\x89PNG"
    grid = [c for c in calls if c["method"] == "grid-cache"]
    assert grid and all(c["params"]["cache"] == {"preset": "cpu"} for c in grid)
    assert result.settings["runs' grid presets"] == ["cpu"]
    assert all(p.values for p in result.points)
    assert all(e.ci95 is not None for p in result.points for e in p.values.values()
               if e.value is not None and p.series != "PT (survival 90%)"
               and "ms" not in str(e.note or "ms"))
    table = paths["markdown"].read_text()
    assert "[0.0" in table or "[0.1" in table   # intervals printed beside the values
    if module is vt_fig7:
        assert {c["params"]["rr_survival"] for c in grid} == set(vt_fig7.SURVIVALS)
        assert {c["max_depth"] for c in grid} == {vt_fig7.MAX_DEPTH}
    if module is vt_fig9:   # every target's line has its marker at N = s
        assert sum(vt_fig9.at_target(p) for p in result.points) == 2 * len(budget.values)
    if module is vt_table1:   # the paper's path length beside ours
        door = next(p for p in result.points if (p.series, p.x) == ("var-bound (t)", 1.0))
        assert door.paper["path_length"] == 7.41 and "| 7.41 |" in table


def _fig7_points(length: dict[float, tuple[float, float]], rvar: dict[float, tuple[float, float]],
                 bias: tuple[float, float]) -> list[Point]:
    """Two thresholds per survival; ``length``/``rvar``: survival -> value at each t (a
    narrow interval), ``bias``: rBias² at each t (every survival alike)."""
    def near(value: float) -> Estimate:
        return Estimate(value=value, ci95=[0.95 * value - 0.01, 1.05 * value + 0.01])
    return [Point(scene="door", series=f"survival {s:.0%}", x=t,
                  values={"path_length": near(length[s][i]), "rvar": near(rvar[s][i]),
                          "rbias2": near(bias[i]), "mse": near(bias[i])})
            for s in vt_fig7.SURVIVALS for i, t in enumerate((0.01, 10.0))]


def test_fig7_verdicts_follow_the_intervals() -> None:
    length = {1.0: (4.0, 15.0), 0.6: (3.0, 6.0), 0.2: (2.0, 5.0)}
    rvar = {1.0: (1.0, 2.0), 0.6: (5.0, 10.0), 0.2: (50.0, 100.0)}
    first, second, third = vt_fig7.verdicts(_fig7_points(length, rvar, (1.0, 0.1)))
    assert first.verdict == "not comparable" and "relative" in first.reason
    assert (second.verdict, third.verdict) == ("holds", "holds")
    # planted: bias rising with t, paths longer at low survival, variance intervals overlapping
    assert vt_fig7.length_and_bias(_fig7_points(length, rvar, (0.1, 1.0))).verdict \
        == "does not hold"
    reversed_ = {1.0: length[0.2], 0.6: length[0.6], 0.2: length[1.0]}
    assert vt_fig7.survival_order(_fig7_points(reversed_, rvar, (1.0, 0.1))).verdict \
        == "does not hold"
    level = {s: (5.0, 5.0) for s in rvar}
    assert vt_fig7.survival_order(_fig7_points(length, level, (1.0, 0.1))).verdict \
        == "not comparable"


def _fig9_points(mse: dict[str, float]) -> list[Point]:
    """Lines with the same MSE at every N (a ±10 % interval), on one scene; ``mse`` by
    series."""
    return [Point(scene="white-room", series=series, x=n,
                  values={"mse": Estimate(value=value, ci95=[0.9 * value, 1.1 * value])})
            for series, value in mse.items() for n in vt_fig9.SAMPLE_COUNTS]


def test_fig9_verdicts_follow_the_intervals() -> None:
    lines = {"mse-min s = 1": 1.0, "mse-min s = 10": 2.0, vt_fig9.PT: 5.0}
    first, second = vt_fig9.verdicts(_fig9_points(lines))
    assert (first.verdict, second.verdict) == ("holds", "holds")    # s = 1 lowest at N = 1
    assert "1 of 2 lowest" in first.reason
    # planted: s = 1's line level with s = 10's; then beaten at both targets; PT lowest
    assert vt_fig9.lowest_at_target(_fig9_points({**lines, "mse-min s = 1": 2.05})).verdict \
        == "not comparable"
    beaten = {**lines, "area-spread c = 0.01": 0.5}
    assert vt_fig9.lowest_at_target(_fig9_points(beaten)).verdict == "does not hold"
    assert vt_fig9.favourable_below_100(_fig9_points({**lines, vt_fig9.PT: 0.5})).verdict \
        == "does not hold"
    assert vt_fig9.favourable_below_100(_fig9_points({**lines, vt_fig9.PT: 2.1})).verdict \
        == "not comparable"


def _table1_points(area_spread: float, lengths: tuple[float, ...],
                   times: tuple[float, ...]) -> list[Point]:
    """Both scenes alike: area-spread c = 0.01's path length and var-bound's at each t
    (±0.1 intervals, times ±5 %)."""
    def near(value: float, half: float) -> Estimate:
        return Estimate(value=value, ci95=[value - half, value + half])
    rows = [("area-spread (c)", 0.01, area_spread, 1.0)]
    rows += [("var-bound (t)", t, length, time)
             for t, length, time in zip((0.01, 0.1, 1.0), lengths, times, strict=True)]
    return [Point(scene=scene, series=series, x=x, values={
        "path_length": near(length, 0.1), "tracer_ms": near(time, 0.05 * time)})
        for scene in vt_table1.SCENES for series, x, length, time in rows]


def test_table1_verdicts_follow_the_intervals() -> None:
    first, second = vt_table1.verdicts(_table1_points(1.95, (2.0, 4.0, 6.0), (1.0, 2.0, 3.0)))
    assert (first.verdict, second.verdict) == ("holds", "holds")
    # planted: paths of 3 vertices; an interval across 2.2; a shorter path at a larger t
    assert vt_table1.area_spread_near_two(_table1_points(3.0, (2.0, 4.0, 6.0),
                                                         (1.0, 2.0, 3.0))).verdict \
        == "does not hold"
    assert vt_table1.area_spread_near_two(_table1_points(2.2, (2.0, 4.0, 6.0),
                                                         (1.0, 2.0, 3.0))).verdict \
        == "not comparable"
    assert vt_table1.longer_with_threshold(_table1_points(2.0, (2.0, 6.0, 4.0),
                                                          (1.0, 2.0, 3.0))).verdict \
        == "does not hold"
    no_interval = _table1_points(2.0, (2.0, 4.0, 6.0), (1.0, 2.0, 3.0))
    for p in no_interval:
        p.values["tracer_ms"] = Estimate(value=p.values["tracer_ms"].value)
    verdict = vt_table1.longer_with_threshold(no_interval)
    assert verdict.verdict == "not comparable" and "without intervals" in verdict.reason
