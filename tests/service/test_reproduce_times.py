"""What reproducing a figure took: its provenance records wall and CPU seconds (child
processes' CPU included) and the load average at start and end; ``reproduce --all``
prints a time per figure and the total, and says when the total is over make
reproduce's 60-minute goal without changing its exit status; ``reproduce list`` shows
the latest stored time of a figure. Fake figures: nothing renders."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from datetime import UTC, datetime, timedelta
from unittest import mock

import pytest
from typer.testing import CliRunner

from jobs.reproduce import registry, run
from jobs.reproduce.registry import Context, FigureSpec
from jobs.reproduce.results import FigureTime, Reproduction
from service import reproduce_command
from service.cli import app, main
from service.reproduce_command import GOAL_S, time_summary
from tests.service.test_reproduce_jobs import (  # noqa: F401 - a fixture
    FAKE_BUDGET,
    _draw,
    _measure,
    fake_figure,
)

#: The CPU seconds a child process burns, and the seconds the figure sleeps.
CHILD_CPU_S = SLEEP_S = 0.2
BURN = ("import time\nstart = time.process_time()\n"
        f"while time.process_time() - start < {CHILD_CPU_S}: pass")


def _burn_in_a_child() -> None:
    subprocess.run([sys.executable, "-c", BURN], check=True)


def _sleeping_figure(ctx: Context) -> Reproduction:
    """Sleeps, and burns CPU in a child process."""
    time.sleep(SLEEP_S)
    _burn_in_a_child()
    return _measure(ctx)


def _cli(argv: list[str], capsys) -> tuple[int, str]:
    with mock.patch.object(sys, "argv", ["nirc-bench", *argv]), \
            pytest.raises(SystemExit) as exit_info:
        main()
    return exit_info.value.code, capsys.readouterr().out


def test_a_reproduction_records_its_wall_and_cpu_seconds_and_the_load(
        tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(registry._FIGURES, ("vt", "fig98"), FigureSpec(
        paper="vt", key="fig98", title="a figure that sleeps and spawns",
        budgets={"quick": FAKE_BUDGET, "full": FAKE_BUDGET}, measure=_sleeping_figure,
        draw=_draw))
    monkeypatch.setattr(registry, "figure_modules", lambda: [])   # no real figure's import
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    code, text = _cli(["reproduce", "vt", "fig98", "--data-dir", str(tmp_path), "--json"],
                      capsys)
    assert code == 0, text
    provenance = json.loads((tmp_path / "reproduce" / "vt-fig98" / "provenance.json")
                            .read_text())
    took = FigureTime.model_validate(provenance["time"])
    assert provenance["mode"] == "quick" and provenance["job_id"] is None
    assert took.wall_s >= SLEEP_S + CHILD_CPU_S
    assert took.cpu_s >= CHILD_CPU_S                  # the child's CPU counts
    assert took.cpu_s <= took.wall_s - SLEEP_S / 2    # the sleep does not
    for load in (took.load_start, took.load_end):
        assert len(load) == 3 and all(math.isfinite(v) and v >= 0 for v in load)
    # Planted: a clock of this process's own CPU alone misses the child's.
    monkeypatch.setattr(run, "_cpu_s", lambda: os.times().user + os.times().system)
    clock = run.Clock()
    _burn_in_a_child()
    assert clock.read().cpu_s < CHILD_CPU_S


def test_all_prints_each_figure_s_time_and_the_total_and_the_goal_keeps_the_exit_status(
        tmp_path, monkeypatch, capsys, fake_figure):  # noqa: F811 - the imported fixture
    monkeypatch.setattr(registry, "_FIGURES", {("vt", "fig99"): fake_figure})
    monkeypatch.setattr(registry, "figure_modules", lambda: [])
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    argv = ["reproduce", "--all", "--data-dir", str(tmp_path)]
    code, text = _cli(argv, capsys)
    assert code == 0, text
    assert "reproducing vt fig99 (quick)" in text                 # none stored before
    assert "vt fig99: took wall " in text                         # as it ends
    assert "\nvt fig99: wall " in text and "total: wall " in text  # in the summary
    assert "over the" not in text
    # Again, under a goal it cannot meet: it says so, and still exits 0; the plan shows
    # the time stored by the first run.
    monkeypatch.setattr(reproduce_command, "GOAL_S", 1e-3)
    code, text = _cli(argv, capsys)
    assert code == 0, text
    assert "reproducing vt fig99 (quick; last here: wall " in text
    assert "over the 0-minute goal" in text


def test_options_before_a_figure_are_refused_not_dropped(
        tmp_path, monkeypatch, capsys, fake_figure):  # noqa: F811 - the imported fixture
    """--data-dir and --quick/--full before the figure belong to --all: with a figure they
    are refused (dropped, the figure would render quick into the default data folder);
    after it they apply. A regression writes into the default folder set here."""
    monkeypatch.setattr(registry, "_FIGURES", {("vt", "fig99"): fake_figure})
    monkeypatch.setattr(registry, "figure_modules", lambda: [])
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    default, chosen = tmp_path / "default", tmp_path / "chosen"
    monkeypatch.setenv("NIRC_BENCH_DATA_DIR", str(default))
    for before in (["--data-dir", str(chosen)], ["--full"]):
        with mock.patch.object(sys, "argv", ["nirc-bench", "reproduce", *before, "vt", "fig99"]), \
                pytest.raises(SystemExit) as exit_info:
            main()
        assert exit_info.value.code != 0
        assert "give them after the figure" in capsys.readouterr().err
    assert not (default / "reproduce").exists() and not (chosen / "reproduce").exists()
    code, text = _cli(["reproduce", "vt", "fig99", "--data-dir", str(chosen)], capsys)
    assert code == 0, text
    assert (chosen / "reproduce" / "vt-fig99").is_dir() and not (default / "reproduce").exists()


def _time(wall_s: float) -> FigureTime:
    return FigureTime(wall_s=wall_s, cpu_s=wall_s / 2, load_start=[1.0, 1.0, 1.0],
                      load_end=[2.0, 2.0, 2.0])


def test_the_goal_is_the_total_wall_time_of_an_hour():
    half = GOAL_S / 2
    under = time_summary([("a", _time(half - 1)), ("b", _time(half))])
    over = time_summary([("a", _time(half + 1)), ("b", _time(half))])
    assert under == ["a: wall 1799.0 s, CPU 899.5 s (load 1.00 -> 2.00)",
                     "b: wall 1800.0 s, CPU 900.0 s (load 1.00 -> 2.00)",
                     "total: wall 3599 s (60.0 min), CPU 1800 s"]
    assert over[2:] == ["total: wall 3601 s (60.0 min), CPU 1800 s",
                        "over the 60-minute goal by 0.0 min"]


def test_list_shows_the_latest_stored_time_of_a_figure(tmp_path):
    folder = tmp_path / "reproduce" / "vt-fig7"
    now = datetime.now(UTC)
    for path, days, wall_s in ((folder / "provenance.json", 2, 50.0),
                               (folder / "job-3" / "provenance.json", 1, 42.0),
                               (folder / "job-2" / "provenance.json", 3, 99.0)):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({
            "mode": "quick", "git_commit": "c", "libraries": {},
            "finished_at": (now - timedelta(days=days)).isoformat(),
            "time": _time(wall_s).model_dump()}))
    (folder / "job-4").mkdir()
    (folder / "job-4" / "provenance.json").write_text("{damaged")   # passed over
    result = CliRunner().invoke(app, ["reproduce", "list", "--data-dir", str(tmp_path)])
    assert result.exit_code == 0, result.output
    fig7 = result.output.split("[VTT24] fig7:")[1].split("\n\n")[0]
    assert "  last here: wall 42.0 s, CPU 21.0 s (load 1.00 -> 2.00), quick, " in fig7
    assert "last here" not in result.output.split("[VTT24] fig9:")[1].split("\n\n")[0]
    rows = json.loads(CliRunner().invoke(
        app, ["reproduce", "list", "--json", "--data-dir", str(tmp_path)]).output)
    [row] = [row for row in rows if (row["paper"], row["figure"]) == ("vt", "fig7")]
    assert row["last_time"]["wall_s"] == 42.0 and row["last_time"]["mode"] == "quick"
