"""Room on disk and connections, against a real `nirc-bench serve` whose Dask
scheduler has no worker (every job stays queued, nothing renders).

On SQLite and PostgreSQL, one service each with a tiny key quota and retention every
second: a key past its quota is answered 507 naming the quota with the numbers, while
an identical spec of its stored or queued jobs (and a replayed Idempotency-Key) is
answered with that job, since it writes nothing more (before: 507); another key is
not held back; the service removes old unnamed runs' artifacts on its own and spares
named, tagged and young runs.

On one service whose free-space floor lies above any disk's free space (the floor is
what refuses, the disk is not filled) and which takes at most MAX_CONNECTIONS
connections at once: jobs, sweeps and uploads are 507 naming the floor; with
MAX_CONNECTIONS connections open another one's request is answered 503 in JSON
(before: 200, and thousands of connections were held), and once one closes a request is served.
"""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path

import httpx
import pytest
from sqlalchemy import update

from jobs.protocol.job import RenderJob
from jobs.protocol.spec import RenderSpec
from jobs.record.artifacts import ArtifactStore
from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.record.models import Job, Run
from jobs.record.store import Store
from tests.jobs.factories import artifact_fields, run_fields
from tests.pg import postgres_database
from tests.service.live import Scheduler, Service, create_key, start_together, stop_together

SPEC = {"scene": "cornell-box", "method": "pt", "resolution": 16, "spp": 1, "frames": 2,
        "seeds": 2, "reference": {"spp": 64, "spp_per_pass": 8}}
SCENE = {"xml": '<scene version="3.0.0"><shape type="sphere"/></scene>'}
#: A floor above any disk's free space (1 EiB).
FLOOR_BYTES = 2**60
MAX_CONNECTIONS = 4
#: Seconds between the tight service's retention rounds.
RETENTION_INTERVAL_S = 1.0


def estimate(spec: dict) -> int:
    """A render's estimated files as the service makes them (no reference stored)."""
    from jobs.execution.queued import QueuedRender

    return QueuedRender(job=RenderJob.parse(RenderSpec(**spec))).work().artifact_bytes


#: Two renders' estimates and a half: a key's third queued render is over it.
QUOTA_BYTES = int(2.5 * estimate(SPEC))


def post(service: Service, key: str, path: str, body: dict, **headers: str) -> httpx.Response:
    return httpx.post(f"{service.url}/api/v1/{path}", json=body, timeout=30,
                      headers={"X-API-Key": key, **headers})


@dataclass(frozen=True)
class Bounded:
    """A service with a tiny key quota and retention every second, with its store
    opened here and their settings."""

    service: Service
    store: Store
    settings: Settings


@pytest.fixture(scope="module")
def services(tmp_path_factory) -> Iterator[dict[str, Bounded | Service]]:
    """One workerless scheduler and, started together, the bounded service on SQLite
    and on PostgreSQL and the tight one (``sqlite``, ``postgresql``, ``tight``)."""
    with ExitStack() as stack:
        scheduler = Scheduler()
        stack.callback(scheduler.stop)
        scheduler.start()
        bounded = {}
        for database in ("sqlite", "postgresql"):
            data = tmp_path_factory.mktemp(database) / "data"
            url = stack.enter_context(postgres_database()) if database == "postgresql" else None
            service = Service(data, scheduler=scheduler.address, database_url=url)
            service.env.update({
                "NIRC_BENCH_KEY_QUOTA_BYTES": str(QUOTA_BYTES),
                "NIRC_BENCH_RETENTION_INTERVAL_H": str(RETENTION_INTERVAL_S / 3600),
                "NIRC_BENCH_ARTIFACT_KEEP_DAYS": "30"})
            settings = Settings(data_dir=data, database_url=url)
            store = open_store(settings)
            stack.callback(store.close)
            bounded[database] = Bounded(service, store, settings)
        tight = Service(tmp_path_factory.mktemp("tight") / "data", scheduler=scheduler.address)
        tight.env.update({"NIRC_BENCH_MIN_FREE_BYTES": str(FLOOR_BYTES),
                          "NIRC_BENCH_MAX_CONNECTIONS": str(MAX_CONNECTIONS)})
        started = [tight, *(each.service for each in bounded.values())]
        stack.callback(stop_together, *started)
        start_together(*started)
        yield {**bounded, "tight": tight}


@pytest.fixture(params=["sqlite", "postgresql"])
def bounded(request, services) -> Bounded:
    return services[request.param]


@pytest.fixture
def tight(services) -> Service:
    """The service under a free-space floor of FLOOR_BYTES, taking MAX_CONNECTIONS
    connections at once (SQLite)."""
    return services["tight"]


def _finish(store: Store, job_id: int, run_bytes: int) -> None:
    """Job ``job_id`` succeeded with a stored run of one ``run_bytes`` artifact."""
    run = store.add_run(run_fields(), [], [{**artifact_fields("image", "a" * 64),
                                            "path": "aa/stored.exr", "bytes": run_bytes}])
    with store.session(write=True) as session:
        session.execute(update(Job).where(Job.id == job_id)
                        .values(status="succeeded", run_id=run.id))


def test_a_key_past_its_quota_is_507_but_gets_its_existing_jobs(bounded):
    service, store = bounded.service, bounded.store
    a, b = service.key, create_key(service.env)
    each = estimate(SPEC)
    first = post(service, a, "jobs", SPEC)
    second = post(service, a, "jobs", {**SPEC, "frames": 3}, **{"Idempotency-Key": "k2"})
    assert [first.status_code, second.status_code] == [202, 202], second.text
    over = post(service, a, "jobs", {**SPEC, "frames": 4})
    assert over.status_code == 507, over.text
    body = over.json()
    assert body["limit"] == "key_quota_bytes" and "key_quota_bytes" in body["detail"]
    assert (body["quota_bytes"], body["used_bytes"], body["request_bytes"]) == (
        QUOTA_BYTES, 2 * each, each), body
    assert post(service, b, "jobs", {**SPEC, "frames": 4}).status_code == 202
    # The first job stored a run of twice its estimate: the key holds it and the
    # second's estimate, past its quota.
    _finish(store, first.json()["id"], 2 * each)
    refused = post(service, a, "jobs", {**SPEC, "frames": 5})
    assert refused.status_code == 507, refused.text
    assert (refused.json()["stored_bytes"], refused.json()["queued_bytes"]) == (2 * each, each)
    # What the key already has costs nothing more: answered with the job (before: 507).
    stored = post(service, a, "jobs", SPEC)
    assert stored.status_code == 202, stored.text
    assert (stored.json()["id"], stored.json()["status"]) == (first.json()["id"], "succeeded")
    replayed = post(service, a, "jobs", {**SPEC, "frames": 3}, **{"Idempotency-Key": "k2"})
    assert replayed.status_code == 202 and replayed.json()["id"] == second.json()["id"]


def _old_runs(store: Store, settings: Settings) -> dict[str, tuple[int, Path]]:
    """Runs of 60 days (unnamed, named, tagged) and of 1 day, each with an image of
    its own: name -> (run id, the image's file). Each is stored at 1 day old and aged
    only once labelled: the service's retention rounds run meanwhile, and a named run
    stored old would be an unnamed old run until its label arrives."""
    artifacts = ArtifactStore(settings.artifacts_dir)
    runs = {}
    for name in ("old", "named", "tagged", "young"):
        blob = artifacts.put_bytes(f"retention {name}".encode() * 50, ".exr")
        run = store.add_run(run_fields(created_at=datetime.now(UTC) - timedelta(days=1)),
                            [], [{**artifact_fields("image", blob.sha256), "path": blob.relpath}])
        runs[name] = run.id, artifacts.root / blob.relpath
    store.label_run(runs["named"][0], name="paper figure 3")
    store.label_run(runs["tagged"][0], set_tags={"keep": "yes"})
    with store.session(write=True) as session:
        session.execute(update(Run).where(Run.id.in_([runs[name][0] for name in
                                                      ("old", "named", "tagged")]))
                        .values(created_at=datetime.now(UTC) - timedelta(days=60)))
    return runs


def test_the_service_removes_old_unnamed_runs_artifacts_on_its_own(bounded):
    store = bounded.store
    runs = _old_runs(store, bounded.settings)

    def kept() -> set[str]:
        return {name for name, (run_id, _) in runs.items() if store.get_run(run_id).artifacts}

    deadline = time.monotonic() + 20 * RETENTION_INTERVAL_S
    while "old" in kept() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert kept() == {"named", "tagged", "young"}
    assert {name for name, (_, path) in runs.items() if path.exists()} == kept()


def test_under_the_free_space_floor_new_work_is_507_naming_it(tight):
    answers = [post(tight, tight.key, "jobs", SPEC),
               post(tight, tight.key, "sweeps", {"scene": "cornell-box", "eps": [0.5],
                                                 "seeds": 2, "resolution": 16}),
               post(tight, tight.key, "scenes", SCENE)]
    assert [answer.status_code for answer in answers] == [507] * 3, [a.text for a in answers]
    for answer in answers:
        body = answer.json()
        assert body["limit"] == "min_free_bytes" and "min_free_bytes" in body["detail"]
        assert body["floor_bytes"] == FLOOR_BYTES > body["free_bytes"] > 0, body
    assert tight.get("/api/v1/jobs") == []


def _answer(sock: socket.socket) -> tuple[bytes, set[bytes], bytes]:
    """One kept-alive GET on ``sock``: the answer's status line, headers (lower-case)
    and body."""
    sock.sendall(b"GET /api/v1/scenes HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    answer = b""
    while b"\r\n\r\n" not in answer:
        chunk = sock.recv(65536)
        if not chunk:
            break
        answer += chunk
    head, _, body = answer.partition(b"\r\n\r\n")
    status, *headers = head.split(b"\r\n")
    length = next((int(line.split(b":")[1]) for line in headers
                   if line.lower().startswith(b"content-length:")), 0)
    while len(body) < length and (chunk := sock.recv(65536)):
        body += chunk
    return status, {line.lower() for line in headers}, body


def _request(sock: socket.socket) -> bytes:
    return _answer(sock)[0]


def test_a_connection_past_the_limit_is_answered_503(tight):
    """MAX_CONNECTIONS connections are served and kept open; one more is answered 503;
    once one of them closes, a new connection is served (the control)."""
    opened = [socket.create_connection(("127.0.0.1", tight.port), timeout=10)
              for _ in range(MAX_CONNECTIONS)]
    try:
        assert [_request(sock) for sock in opened] == [b"HTTP/1.1 200 OK"] * MAX_CONNECTIONS
        with socket.create_connection(("127.0.0.1", tight.port), timeout=10) as extra:
            status, headers, body = _answer(extra)
            assert status == b"HTTP/1.1 503 Service Unavailable", (status, body)
            assert b"max_connections" in json.loads(body)["detail"].encode()
            assert {b"retry-after: 1", b"connection: close",
                    b"x-content-type-options: nosniff"} <= headers, headers
        opened.pop().close()
        time.sleep(0.2)         # the service sees it close
        with socket.create_connection(("127.0.0.1", tight.port), timeout=10) as another:
            assert _request(another) == b"HTTP/1.1 200 OK"
    finally:
        for sock in opened:
            sock.close()
