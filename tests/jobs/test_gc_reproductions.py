"""Retention of the reproduced figures (`nirc-bench gc`, the service's rounds), on SQLite
and PostgreSQL: a reproduction that finished longer ago than artifact_keep_days goes
(dated by its provenance, else by its table), the oldest go first while the artifacts
and the reproductions together are over artifact_max_bytes, one that never finished
goes once older than gc_keep_days, and the folder of a reproduce job queued or running
stays whatever its age. Before: gc did not know data/reproduce. Synthetic folders:
nothing renders."""

from __future__ import annotations

import json
import os
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

from jobs.record import gc
from jobs.record.artifacts import ArtifactStore
from jobs.record.models import Job
from jobs.record.store import Store
from jobs.reproduce.job import stored_reproductions
from tests.jobs.factories import artifact_fields, run_fields

TABLE = {"paper": "vt", "figure": "fig7", "title": "t", "mode": "quick", "settings": {},
         "x_label": "t", "quantities": {}, "points": []}


def _job(store: Store, status: str) -> int:
    with store.session(write=True) as session:
        job = Job(kind="reproduce", spec={"paper": "vt", "figure": "fig7"},
                  spec_key=f"reproduce {time.monotonic_ns()}", status=status)
        session.add(job)
        session.flush()
        return job.id


def _age(folder: Path, days: float) -> None:
    past = time.time() - days * 86400
    for path in folder.iterdir():
        os.utime(path, (past, past))


def _stored(folder: Path, finished_days: float | None, *, provenance: bool = True) -> Path:
    """A finished reproduction in ``folder`` (table, PNG and, with ``provenance``, its
    provenance saying it finished ``finished_days`` ago), or, with ``finished_days``
    None, one that never finished (a partial PNG)."""
    folder.mkdir(parents=True, exist_ok=True)
    if finished_days is None:
        (folder / "partial.png").write_bytes(b"p" * 50)
        return folder
    (folder / "table.json").write_text(json.dumps(TABLE))
    (folder / "figure.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"f" * 92)
    if provenance:
        finished = datetime.now(UTC) - timedelta(days=finished_days)
        (folder / "provenance.json").write_text(json.dumps({
            "job_id": None, "git_commit": "c", "libraries": {},
            "finished_at": finished.isoformat()}))
    return folder


def _bytes(folder: Path) -> int:
    return sum(path.stat().st_size for path in folder.iterdir() if path.is_file())


def test_old_and_unfinished_reproductions_go_and_those_of_live_jobs_stay(
        store, settings, monkeypatch):
    policy = settings.model_copy(update={"artifact_keep_days": 365.0})
    figure = settings.reproductions_dir / "vt-fig7"
    # The CLI's, stored before provenance was recorded: dated by its table (400 days).
    _age(_stored(figure, 400, provenance=False), 400)
    jobs = {name: _job(store, status) for name, status in (
        ("old", "succeeded"), ("young", "succeeded"), ("queued-old", "queued"),
        ("running", "running"), ("failed", "failed"), ("failed-young", "failed"))}
    folders = {name: figure / f"job-{job_id}" for name, job_id in jobs.items()}
    _stored(folders["old"], 400)          # its files are new: its provenance dates it
    _stored(folders["young"], 1)
    _stored(folders["queued-old"], 400)   # queued again: kept however old
    _age(_stored(folders["running"], None), 60)
    _age(_stored(folders["failed"], None), 60)
    _stored(folders["failed-young"], None)

    plan = gc.plan(store, policy)
    listed = {(removal.what, removal.path) for removal in plan.removals}
    assert listed == {("reproduction", figure), ("reproduction", folders["old"]),
                      ("unfinished reproduction", folders["failed"])}
    assert plan.bytes == _bytes(figure) + _bytes(folders["old"]) + 50
    # Planted: were queued and running jobs not looked up, their folders would go too.
    monkeypatch.setattr(gc, "active_reproductions", lambda _store: set())
    unguarded = {removal.path for removal in gc.plan(store, policy).removals}
    assert {folders["queued-old"], folders["running"]} <= unguarded
    monkeypatch.undo()

    assert gc.apply(store, policy, plan) == plan.bytes
    assert not folders["old"].exists() and not folders["failed"].exists()
    assert not (figure / "table.json").exists() and figure.is_dir()   # its jobs' stay
    for name in ("young", "queued-old", "running", "failed-young"):
        assert any(folders[name].iterdir()), name
    assert [stored.job_id for stored in stored_reproductions(settings, "vt")] == [
        jobs["queued-old"], jobs["young"]]
    assert gc.plan(store, policy).removals == []


def test_the_oldest_reproductions_and_artifacts_go_first_while_over_the_size_limit(
        store, settings):
    """Reproductions of 3, 2 and 1 days and a run's artifact of 2.5 days, over a limit
    that holds the two newest reproductions: the oldest reproduction and then the run's
    artifact go, in the order of their age."""
    figure = settings.reproductions_dir / "vt-fig7"
    folders = {days: _stored(figure / f"job-{_job(store, 'succeeded')}", days)
               for days in (3, 2, 1)}
    blob = ArtifactStore(settings.artifacts_dir).put_bytes(b"a" * 100, ".exr")
    run = store.add_run(run_fields(created_at=datetime.now(UTC) - timedelta(days=2.5)), [],
                        [{**artifact_fields("image", blob.sha256), "path": blob.relpath,
                          "bytes": 100}])
    policy = settings.model_copy(update={
        "artifact_keep_days": None, "artifact_max_bytes": _bytes(folders[2]) + _bytes(folders[1])})
    plan = gc.plan(store, policy)
    assert [(removal.what, removal.path or removal.owner_id) for removal in plan.removals] == [
        ("reproduction", folders[3]), ("run artifacts", run.id)]
    gc.apply(store, policy, plan)
    assert not folders[3].exists() and folders[2].is_dir() and folders[1].is_dir()
    assert gc.plan(store, policy).removals == []
