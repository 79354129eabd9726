"""A running reproduction's marker and retention: while ``reproduce`` runs (the command
line's, which no job row names) its folder holds a marker naming its process, and gc
neither plans nor applies the removal of that folder, however old its earlier files; the
marker goes at the end, also when the figure fails. A marker whose process is gone (or a
pid started after it: reused) protects nothing: the folder is an unfinished reproduction,
kept until gc_keep_days. A second run into a folder a live process marks is refused.
Before: gc could clear a command line's folder mid-run. Synthetic figures: nothing
renders."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from jobs.record import gc, reproduction_folders
from jobs.record.reproduction_marker import MARKER, FolderBusy, is_running, running_marker
from jobs.reproduce import registry
from jobs.reproduce.registry import Budget, Context, FigureSpec
from jobs.reproduce.results import Reproduction
from jobs.reproduce.run import default_out_dir, reproduce

BUDGET = Budget(resolution=4, seeds=2, frames=1, ref_spp=4, grid_preset="small",
                why="synthetic points: nothing renders")
OLD_DAYS = 400.0

#: The marker is a file: SQLite alone (gc's queries run on both in test_gc_reproductions.py).
SQLITE = pytest.mark.parametrize("settings", ["sqlite"], indirect=True)


def _policy(settings):
    """Finished reproductions go after a year; unfinished ones after gc_keep_days."""
    return settings.model_copy(update={"artifact_keep_days": 365.0})


def _old_reproduction(folder: Path) -> None:
    """A reproduction the command line finished OLD_DAYS ago in ``folder``: past the
    policy, gc removes it."""
    folder.mkdir(parents=True, exist_ok=True)
    finished = datetime.now(UTC) - timedelta(days=OLD_DAYS)
    (folder / "table.json").write_text("{}")
    (folder / "provenance.json").write_text(json.dumps({"finished_at": finished.isoformat()}))


def _planned(store, settings, keep_days: float | None = None) -> dict[Path, str]:
    return {removal.path: removal.what
            for removal in gc.plan(store, settings, keep_days).removals}


def _figure(monkeypatch, measure) -> None:
    spec = FigureSpec(paper="vt", key="fig99", title="a synthetic figure",
                      budgets={"quick": BUDGET, "full": BUDGET}, measure=measure,
                      draw=lambda reproduction, path: path)
    monkeypatch.setitem(registry._FIGURES, ("vt", "fig99"), spec)


def _measured(ctx: Context) -> Reproduction:
    return Reproduction(paper="vt", figure="fig99", title="t", mode="", settings={},
                        x_label="x", quantities={}, points=[])


@SQLITE
def test_gc_leaves_a_running_command_line_reproduction_alone(store, settings, monkeypatch):
    policy = _policy(settings)
    folder = default_out_dir(settings, "vt", "fig99")
    _old_reproduction(folder)
    assert _planned(store, policy) == {folder: "reproduction"}     # not running: it goes
    seen: dict[str, object] = {}

    def measure(ctx: Context) -> Reproduction:
        """Mid-run: gc keeping nothing by age is planned and applied; planted, gc that
        does not ask whether the marker's process lives, and gc blind to the marker."""
        seen["marked"] = is_running(folder)
        seen["planned"] = _planned(store, policy, keep_days=0.0)
        seen["freed"] = gc.apply(store, policy, gc.plan(store, policy, keep_days=0.0))
        with monkeypatch.context() as planted:
            planted.setattr(reproduction_folders, "is_running", lambda _folder: False)
            seen["not asked"] = _planned(store, policy, keep_days=0.0)
        with monkeypatch.context() as planted:
            planted.setattr(reproduction_folders, "MARKER", "no such marker")
            seen["blind"] = _planned(store, policy)
        return _measured(ctx)

    _figure(monkeypatch, measure)
    reproduce("vt", "fig99", "quick", folder, store, settings)
    assert seen == {"marked": True, "planned": {}, "freed": 0,
                    "not asked": {folder: "unfinished reproduction"},
                    "blind": {folder: "reproduction"}}
    assert not (folder / MARKER).exists()                  # released at the end
    assert (folder / "table.json").is_file() and _planned(store, policy) == {}


@SQLITE
def test_the_marker_goes_when_the_figure_fails(store, settings, monkeypatch):
    def measure(ctx: Context) -> Reproduction:
        assert is_running(folder)
        raise RuntimeError("a planted failure")

    folder = default_out_dir(settings, "vt", "fig99")
    _figure(monkeypatch, measure)
    with pytest.raises(RuntimeError, match="planted"):
        reproduce("vt", "fig99", "quick", folder, store, settings)
    assert not folder.exists()              # made for the run, left empty: removed
    folder.mkdir(parents=True)
    with pytest.raises(RuntimeError, match="planted"):
        reproduce("vt", "fig99", "quick", folder, store, settings)
    assert folder.is_dir() and not any(folder.iterdir())   # the caller's (--out) stays


def _mark(folder: Path, pid: int, started_at: datetime, host: str | None = None) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / MARKER).write_text(json.dumps({
        "pid": pid, "host": host or socket.gethostname(), "started_at": started_at.isoformat()}))


def _dead_pid() -> int:
    child = subprocess.Popen(["true"])
    child.wait()
    return child.pid


@SQLITE
def test_a_stale_marker_protects_until_gc_keep_days_only(store, settings):
    """Markers of a process that is gone, of a pid that started after its marker (reused)
    and of another host: each folder, though its provenance says finished long ago, is
    an unfinished reproduction, kept while young and removed once its files are older
    than gc_keep_days. The control: this live process's marker protects an aged folder."""
    policy = _policy(settings)
    now = datetime.now(UTC)
    root = settings.reproductions_dir
    stale = {"gone": (_dead_pid(), now, None), "reused": (os.getpid(), now - timedelta(
        days=OLD_DAYS), None), "elsewhere": (os.getpid(), now, "another-host")}
    for name, (pid, started, host) in stale.items():
        _old_reproduction(root / f"vt-{name}")
        _mark(root / f"vt-{name}", pid, started, host)
    _old_reproduction(root / "vt-live")
    _mark(root / "vt-live", os.getpid(), now)
    assert _planned(store, policy) == {}                   # all young
    past = time.time() - (policy.gc_keep_days + 1) * 86400
    for folder in root.iterdir():
        for path in folder.iterdir():
            os.utime(path, (past, past))
    assert _planned(store, policy) == {root / f"vt-{name}": "unfinished reproduction"
                                      for name in stale}


@SQLITE
def test_gc_applies_no_plan_to_a_folder_whose_run_started_since(store, settings):
    policy = _policy(settings)
    folder = default_out_dir(settings, "vt", "fig99")
    _old_reproduction(folder)
    plan = gc.plan(store, policy)
    with running_marker(folder):
        assert gc.apply(store, policy, plan) == 0
        assert (folder / "table.json").is_file()
    assert gc.apply(store, policy, plan) > 0 and not folder.exists()


def test_a_second_run_into_a_live_marked_folder_is_refused(tmp_path):
    folder = tmp_path / "figure"
    with running_marker(folder):
        with pytest.raises(FolderBusy, match=f"process {os.getpid()}"):
            with running_marker(folder):
                pass
        assert is_running(folder)
    _mark(folder, _dead_pid(), datetime.now(UTC))          # stale: taken over
    with running_marker(folder):
        assert is_running(folder)
    _mark(folder, os.getpid(), datetime.now(UTC), "another-host")   # cannot be checked
    with pytest.raises(FolderBusy, match="another-host"):
        with running_marker(folder):
            pass


def test_the_command_refuses_a_folder_a_live_run_marks_in_one_line(
        tmp_path, monkeypatch, capsys):
    """``nirc-bench reproduce vt fig99`` while another live process writes its folder:
    exit 2, one line naming that process, no traceback, nothing measured; the control,
    the same command once the marker is gone, runs the figure."""
    from service.cli import main

    measured: list[str] = []
    _figure(monkeypatch, lambda ctx: measured.append("ran") or _measured(ctx))
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    monkeypatch.setattr(sys, "argv", ["nirc-bench", "reproduce", "vt", "fig99",
                                      "--data-dir", str(tmp_path)])
    folder = tmp_path / "reproduce" / "vt-fig99"
    with running_marker(folder), pytest.raises(SystemExit) as refused:
        main()
    err = capsys.readouterr().err
    assert refused.value.code == 2 and measured == [], err
    assert "nirc-bench: error:" in err and f"process {os.getpid()}" in err
    assert "Traceback" not in err
    with pytest.raises(SystemExit) as ran:
        main()
    assert ran.value.code in (0, None) and measured == ["ran"], capsys.readouterr()
