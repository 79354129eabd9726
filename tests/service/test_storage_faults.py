"""The service survives its own storage failing, against a real `nirc-bench serve` on
loopback, on SQLite and PostgreSQL.

* A full data folder: every file the service and its render processes write is cut to
  one byte with RLIMIT_FSIZE (``prlimit`` on the running processes: no privileges, no
  mount), while one job renders and another waits for the worker. Before: a new
  submission was answered with a plain-text 500; the rendering job stayed `running`
  and the waiting one `queued` for good (its claim had failed), and only a restart
  dispatched them again. After: 507 with the cause in JSON while the disk is full,
  the job's error names it (when the database can still be written), no empty file
  is stored, and once the disk has room both jobs finish on their own.
* A held database lock (``BEGIN EXCLUSIVE`` on SQLite, ``LOCK TABLE ... ACCESS
  EXCLUSIVE`` on PostgreSQL) for two leases: the running job's heartbeats and the
  waiting job's claim fail. With the re-dispatch timer switched off, submitting the
  same specs again returns the same jobs (202, or 503 naming a job that is still
  stalled) — and they run to the end instead of staying stuck.
"""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import psutil
from sqlalchemy import create_engine, text

from tests.service.live import Service

SPEC = {"scene": "cornell-box", "method": "pt", "resolution": 8, "spp": 1, "frames": 1000,
        "seeds": 1, "reference": {"spp": 64, "spp_per_pass": 8}}
#: A second job of another spec, waiting for the worker behind the first.
WAITING = {**SPEC, "frames": 999}
#: Short database lock timeout (a heartbeat fails after 1 s) and lease (3 s, from
#: tests/service/live.py).
FAST_FAILURE = {"NIRC_BENCH_DB_LOCK_TIMEOUT_S": "1"}
SCENE = ('<scene version="3.0.0"><shape type="sphere"/><emitter type="constant"/>'
         '<sensor type="perspective"><film type="hdrfilm"><integer name="width" value="8"/>'
         '<integer name="height" value="8"/></film></sensor></scene>')


def limit_file_size(service: Service, limit: int) -> None:
    """RLIMIT_FSIZE of the service and every process it started (a process started
    later inherits the service's)."""
    root = psutil.Process(service.proc.pid)
    for process in (root, *root.children(recursive=True)):
        try:
            process.rlimit(psutil.RLIMIT_FSIZE, (limit, psutil.RLIM_INFINITY))
        except psutil.NoSuchProcess:
            pass


def post(service: Service, spec: dict) -> httpx.Response:
    return httpx.post(f"{service.url}/api/v1/jobs", json=spec,
                      headers={"X-API-Key": service.key}, timeout=30)


def resubmit(service: Service, spec: dict) -> dict:
    """The job of ``spec``, submitted again: 202, or 503 naming the job while it is
    stalled (this service's last transition failed); either way it is dispatched again."""
    answer = post(service, spec)
    if answer.status_code == 503:
        assert answer.json()["job"]["stalled"].startswith("storage: "), answer.text
        return answer.json()["job"]
    assert answer.status_code == 202, answer.text
    return answer.json()


def running(job: dict) -> bool:
    return job["status"] == "running" and bool(job["progress"])


def start(tmp_path: Path, database_url: str | None, **env: str) -> Service:
    service = Service(tmp_path / "data", database_url=database_url)
    service.env.update(FAST_FAILURE, **env)
    service.start()
    return service


def test_a_full_data_folder_is_507_and_its_jobs_finish_once_there_is_room(
        tmp_path, database_url):
    root = tmp_path / "scenes"
    root.mkdir()
    (root / "scene.xml").write_text(SCENE)
    service = start(tmp_path, database_url, NIRC_BENCH_REDISPATCH_INTERVAL_S="1",
                    NIRC_BENCH_SCENE_ROOTS=str(root))
    try:
        first, waiting = service.submit(SPEC), service.submit(WAITING)
        service.wait(first["id"], until=running, timeout=120)
        limit_file_size(service, 1)
        try:
            # Staging a scene-root scene writes a copy; on SQLite any job is a write.
            for spec in ([{**SPEC, "scene": "scene.xml"}]
                         + ([{**SPEC, "frames": 7}] if database_url is None else [])):
                answer = post(service, spec)
                assert answer.status_code == 507, answer.text
                assert "storage full" in answer.json()["detail"], answer.text
            if database_url is not None:    # the database still records the cause
                job = service.wait(first["id"], timeout=60, until=lambda j: "storage full"
                                   in (j["error"] or ""))
                assert "could not write" in job["error"] and "SIGKILL" not in job["error"]
                assert job["attempts"] <= 1, job     # a full disk uses up no attempt
            else:
                time.sleep(5)               # past the lease: the runner gives the job up
        finally:
            limit_file_size(service, psutil.RLIM_INFINITY)
        for job in (first, waiting):
            done = service.wait(job["id"], timeout=120)
            assert done["status"] == "succeeded", done
        empty = [path for path in (tmp_path / "data").rglob("*")
                 if path.is_file() and path.stat().st_size == 0
                 and "artifacts" in path.parts]
        assert not empty, empty
    finally:
        service.stop()


@contextmanager
def database_locked(data_dir: Path, database_url: str | None) -> Iterator[None]:
    """The jobs table locked against writes (SQLite: the whole database) by another
    connection, as a long migration or a stuck client would hold it."""
    if database_url is None:
        connection = sqlite3.connect(data_dir / "nirc-bench.db", timeout=30,
                                     isolation_level=None)
        connection.execute("BEGIN EXCLUSIVE")
        try:
            yield
        finally:
            connection.execute("ROLLBACK")
            connection.close()
        return
    engine = create_engine(database_url)
    with engine.connect() as connection:
        transaction = connection.begin()
        connection.execute(text("LOCK TABLE jobs IN ACCESS EXCLUSIVE MODE"))
        try:
            yield
        finally:
            transaction.rollback()
    engine.dispose()


def test_a_held_database_lock_leaves_no_job_stuck(tmp_path, database_url):
    # No re-dispatch on a timer: only submitting the same spec again may revive a job.
    service = start(tmp_path, database_url, NIRC_BENCH_REDISPATCH_INTERVAL_S="3600")
    try:
        first, waiting = service.submit(SPEC), service.submit(WAITING)
        service.wait(first["id"], until=running, timeout=120)
        with database_locked(tmp_path / "data", database_url):
            time.sleep(7)       # two leases without a heartbeat; the waiting claim fails
            if database_url is not None:    # reads wait for the lock, then answer 503
                answer = httpx.get(f"{service.url}/api/v1/jobs/{first['id']}", timeout=30)
                assert answer.status_code == 503, answer.text
                assert "database unavailable" in answer.json()["detail"]
        again = [resubmit(service, SPEC), resubmit(service, WAITING)]
        assert [job["id"] for job in again] == [first["id"], waiting["id"]]
        for job in again:
            done = service.wait(job["id"], timeout=120)
            assert done["status"] == "succeeded", done
    finally:
        service.stop()


def test_held_database_locks_use_up_no_attempt_and_show_the_job_stalled(
        tmp_path, database_url):
    """A lock past a lease while one job renders: before, it cost the job an attempt (the
    runner gave it up, and the takeover counted one more), so three such locks ended it
    `failed` for good. One lock shows it: the job must still be on its first attempt."""
    service = start(tmp_path, database_url, NIRC_BENCH_REDISPATCH_INTERVAL_S="1")
    try:
        job = service.submit({**SPEC, "frames": 50_000})
        service.wait(job["id"], until=lambda j: running(j) and j["stalled"] is None,
                     timeout=120)
        with database_locked(tmp_path / "data", database_url):
            time.sleep(5)       # past the lease (3 s) plus the lock timeout (1 s)
            if database_url is None:    # SQLite's readers are not locked out
                stalled = service.get(f"/api/v1/jobs/{job['id']}")["stalled"] or ""
                assert stalled.startswith("storage: database unavailable"), stalled
        time.sleep(2)           # requeued, dispatched and claimed again
        job = service.wait(job["id"], until=lambda j: j["status"] in ("running", "failed"),
                           timeout=60)
        assert job["status"] == "running" and job["attempts"] == 1, job
    finally:
        service.stop()
