"""Room for new work over REST, on SQLite and PostgreSQL: a key's quota counts its
stored artifacts, its uploads and the estimated files of its queued jobs (507 naming
the quota, the usage and the request's estimate; another key unaffected); the
free-space floor refuses jobs, sweeps and uploads (507); a resubmission of a stalled
job says so (503 with the job). Before: no quota, no floor, and a stalled job was
answered 202 like any accepted one. Each test plants the defect it guards against
(the counting or the check removed) and shows the outcome changes."""

from __future__ import annotations

import os
import shutil
from datetime import UTC, datetime, timedelta
from types import SimpleNamespace

import pytest
from sqlalchemy import update

from jobs.execution import queue as queue_module
from jobs.execution.queued import QueuedRender
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import RenderSpec
from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.record.models import Job
from service.api import quota
from tests.jobs.factories import artifact_fields, run_fields
from tests.support.two_keys import two_key_clients

SPEC = {"scene": "cornell-box", "method": "pt", "resolution": 16, "spp": 1, "frames": 2,
        "seeds": 2, "reference": {"spp": 64, "spp_per_pass": 8}}
SCENE = {"xml": '<scene version="3.0.0"><shape type="sphere"/></scene>'}


def estimate(spec: dict) -> int:
    """The request's estimate as the service makes it (no reference stored)."""
    return QueuedRender(job=RenderJob.parse(RenderSpec(**spec))).work().artifact_bytes


@pytest.fixture
def api(tmp_path, monkeypatch, database_url):
    """make(**settings) -> (client of key A, client of key B, store): the app without a
    dispatcher (jobs stay queued) on the test's database."""
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    opened = []

    def make(**overrides):
        settings = Settings(data_dir=tmp_path / "data", database_url=database_url, **overrides)
        store = open_store(settings)
        opened.append(store)
        return *two_key_clients(settings, store), store

    yield make
    for store in opened:
        store.close()


def _finish(store, job_id: int, run_bytes: int) -> None:
    """Job ``job_id`` succeeded with a stored run of one ``run_bytes`` artifact."""
    run = store.add_run(run_fields(), [], [{**artifact_fields("image", "a" * 64),
                                            "path": "aa/stored.exr", "bytes": run_bytes}])
    with store.session(write=True) as session:
        session.execute(update(Job).where(Job.id == job_id)
                        .values(status="succeeded", run_id=run.id))


def _cancel(store, *job_ids: int) -> None:
    with store.session(write=True) as session:
        session.execute(update(Job).where(Job.id.in_(job_ids)).values(status="canceled"))


def test_a_key_over_its_quota_is_507_with_the_numbers_and_others_are_unaffected(
        api, monkeypatch):
    each = estimate(SPEC)
    client, other, store = api(key_quota_bytes=int(2.5 * each))

    def submit(who, frames: int):
        return who.post("/api/v1/jobs", json={**SPEC, "frames": frames})

    first, second = submit(client, 2), submit(client, 3)
    assert [first.status_code, second.status_code] == [202, 202]
    # Two queued jobs' estimates and this one's pass the quota: counted while queued.
    third = submit(client, 4)
    assert third.status_code == 507, third.text
    body = third.json()
    assert body["limit"] == "key_quota_bytes" and "key_quota_bytes" in body["detail"]
    # A quota of kilobytes reads in kilobytes, not as '0.000 GiB'.
    assert f"quota of {quota.readable_size(int(2.5 * each))} " in body["detail"]
    assert "0.000" not in body["detail"], body["detail"]
    assert (body["quota_bytes"], body["used_bytes"], body["queued_bytes"],
            body["request_bytes"]) == (int(2.5 * each), 2 * each, 2 * each, each), body
    assert submit(other, 4).status_code == 202          # another key: its own quota
    with monkeypatch.context() as planted:              # queued jobs not counted
        planted.setattr(quota, "queued_bytes", lambda store, key_id: 0)
        accepted = submit(client, 4)
        assert accepted.status_code == 202, accepted.text
    # One job stored a run of 2 x each bytes, the others were canceled: the stored
    # bytes count, the canceled jobs nothing.
    _finish(store, first.json()["id"], 2 * each)
    _cancel(store, second.json()["id"], accepted.json()["id"])
    after = submit(client, 5)
    assert after.status_code == 507, after.text
    assert (after.json()["stored_bytes"], after.json()["queued_bytes"]) == (2 * each, 0)
    with monkeypatch.context() as planted:              # stored runs not counted
        planted.setattr(quota, "stored_bytes", lambda store, settings, key_id: 0)
        assert submit(client, 5).status_code == 202


def test_a_key_s_uploads_count_in_its_quota(api):
    """A scene upload is refused past the quota with its size as the request; a stored
    upload counts for the key that sent it, not for another."""
    size = len(SCENE["xml"])
    client, other, store = api(key_quota_bytes=estimate(SPEC) + size // 2)
    stored = client.post("/api/v1/scenes", json=SCENE)
    assert stored.status_code == 201, stored.text
    refused = client.post("/api/v1/jobs", json=SPEC)
    assert refused.status_code == 507, refused.text
    assert refused.json()["stored_bytes"] == stored.json()["bytes"] > size // 2
    assert other.post("/api/v1/jobs", json=SPEC).status_code == 202
    tight, _, _ = api(key_quota_bytes=size - 1)
    big = tight.post("/api/v1/scenes", json=SCENE)
    assert big.status_code == 507 and big.json()["request_bytes"] == size, big.text


@pytest.mark.parametrize("free_fraction", [0.01, 0.5])
def test_under_the_free_space_floor_new_work_is_507(api, monkeypatch, free_fraction):
    """A 100 GiB disk with 1 % free is under the floor (the larger of 2 GiB and 5 %):
    jobs, sweeps and scene uploads are refused; with half of it free they pass (the
    control: the same requests, the floor not reached)."""
    total = 100 * quota.GIB
    disk = SimpleNamespace(total=total, used=0, free=int(free_fraction * total))
    monkeypatch.setattr(shutil, "disk_usage", lambda path: disk)
    client, _, _ = api()
    answers = [client.post("/api/v1/jobs", json=SPEC),
               client.post("/api/v1/sweeps", json={"scene": "cornell-box", "eps": [0.5],
                                                   "seeds": 2, "resolution": 16}),
               client.post("/api/v1/scenes", json=SCENE)]
    if free_fraction < 0.05:
        assert [a.status_code for a in answers] == [507] * 3, [a.text for a in answers]
        body = answers[0].json()
        assert body["limit"] == "min_free_bytes" and body["floor_bytes"] == 5 * quota.GIB
        assert body["free_bytes"] == quota.GIB and "min_free_fraction" in body["detail"]
    else:
        assert [a.status_code for a in answers] == [202, 202, 201], [a.text for a in answers]


def test_a_resubmitted_stalled_job_is_503_naming_it(api, monkeypatch):
    """A running job whose lease expired while the service cannot write its database:
    before, its resubmission was a 202 like any accepted job (the reason only in a
    field); now 503 with Retry-After, the reason and the job. The same job without the
    storage failure (the control) is answered 202."""
    client, _, store = api()
    job = client.post("/api/v1/jobs", json=SPEC).json()
    with store.session(write=True) as session:
        session.execute(update(Job).where(Job.id == job["id"]).values(
            status="running", updated_at=datetime.now(UTC) - timedelta(minutes=5)))
    assert client.post("/api/v1/jobs", json=SPEC).status_code == 202       # control
    monkeypatch.setattr(queue_module.STORAGE_FAULT, "reason", "database unavailable: locked")
    again = client.post("/api/v1/jobs", json=SPEC)
    assert again.status_code == 503, again.text
    assert again.headers["Retry-After"] and again.headers["Location"] == f"/api/v1/jobs/{job['id']}"
    body = again.json()
    assert body["job"]["id"] == job["id"]
    assert body["job"]["stalled"] == "storage: database unavailable: locked"
    assert f"job {job['id']} of this spec is stalled" in body["detail"]


def test_serve_takes_the_key_quota_from_its_flag_or_the_environment(tmp_path, monkeypatch):
    """`serve --key-quota-bytes N` (0: no quota) over NIRC_BENCH_KEY_QUOTA_BYTES over
    the 10 GiB default: the settings the app is built with."""
    from typer.testing import CliRunner

    from service.cli import app

    built = []

    class Dispatcher:
        dashboard_url = None

        def __init__(self, *args, **kwargs):
            pass

        def close(self):
            pass

    monkeypatch.setattr("jobs.execution.dispatch.Dispatcher", Dispatcher)
    monkeypatch.setattr("service.api.main.create_app",
                        lambda settings, dispatcher: built.append(settings.key_quota_bytes))
    monkeypatch.setattr("uvicorn.run", lambda *args, **kwargs: None)
    umask = os.umask(0o022)         # serve sets the process's umask: put it back after
    os.umask(umask)
    try:
        serve = ["serve", "--data-dir", str(tmp_path / "data")]
        for args, env in (([], None), (["--key-quota-bytes", "5000"], "7"),
                          (["--key-quota-bytes", "0"], None), ([], "0"), ([], "7")):
            if env is None:
                monkeypatch.delenv("NIRC_BENCH_KEY_QUOTA_BYTES", raising=False)
            else:
                monkeypatch.setenv("NIRC_BENCH_KEY_QUOTA_BYTES", env)
            result = CliRunner().invoke(app, [*serve, *args])
            assert result.exit_code == 0, result.output
    finally:
        os.umask(umask)
    assert built == [10 * quota.GIB, 5000, None, None, 7]
