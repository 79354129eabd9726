"""Stored reproductions in the service's room for new work: a reproduce job's folder
counts in its key's quota (the command line's in no key's) and every reproduction in
the data folder's size, so a submission past either bound is refused with 507 like any
job's. Before: data/reproduce was counted in neither, and these submissions passed; each
test plants that (the reproductions not counted) and shows the submission accepted.
The figures are fakes registered here: nothing renders."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import update

from jobs.execution import work
from jobs.execution.work import data_bytes
from jobs.record import usage
from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.record.models import Job
from jobs.reproduce import registry
from jobs.reproduce.job import REPRODUCTION_BYTES, ReproduceSpec, job_dir
from jobs.reproduce.registry import Budget, FigureSpec
from jobs.reproduce.run import default_out_dir
from tests.support.two_keys import two_key_clients

BUDGET = Budget(resolution=4, seeds=2, frames=1, ref_spp=4, grid_preset="small",
                why="synthetic: never run here")
#: A stored reproduction's bytes: large beside the database's growth during a test.
STORED = 1 << 20


@pytest.fixture
def figures(monkeypatch):
    for key in ("fig98", "fig99"):
        monkeypatch.setitem(registry._FIGURES, ("vt", key), FigureSpec(
            paper="vt", key=key, title="a synthetic figure", budgets={"quick": BUDGET,
                                                                        "full": BUDGET},
            measure=lambda ctx: None, draw=lambda reproduction, path: path))


@pytest.fixture
def service(data_folder, monkeypatch, figures):
    """make(**settings) -> (client of key A, client of key B, store, settings)."""
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    opened = []

    def make(**limits):
        settings = Settings(data_dir=data_folder, max_job_seconds=24 * 3600.0, **limits)
        store = open_store(settings)
        opened.append(store)
        return *two_key_clients(settings, store), store, settings

    yield make
    for store in opened:
        store.close()


def _submit(client: TestClient, figure: str, mode: str = "quick"):
    return client.post("/api/v1/reproductions",
                       json={"paper": "vt", "figure": figure, "mode": mode})


def _write(folder: Path, n_bytes: int) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "figure.png").write_bytes(b"p" * n_bytes)


def test_a_key_s_stored_reproductions_count_in_its_quota(service, monkeypatch):
    """Key A's finished reproduction of STORED bytes and the next one's estimate pass its
    quota: 507 naming the quota with the stored bytes its job's folder holds (a command
    line's ten times larger counts for no key); key B is not charged for it."""
    client, other, store, settings = service(key_quota_bytes=REPRODUCTION_BYTES + STORED // 2)
    first = _submit(client, "fig98")
    assert first.status_code == 202, first.text
    job_id = first.json()["id"]
    with store.session(write=True) as session:
        session.execute(update(Job).where(Job.id == job_id).values(status="succeeded"))
    _write(job_dir(settings, ReproduceSpec(paper="vt", figure="fig98"), job_id), STORED)
    _write(default_out_dir(settings, "vt", "fig98"), 10 * STORED)
    refused = _submit(client, "fig99")
    assert refused.status_code == 507, refused.text
    body = refused.json()
    assert (body["limit"], body["stored_bytes"], body["queued_bytes"], body["request_bytes"]) \
        == ("key_quota_bytes", STORED, 0, REPRODUCTION_BYTES), body
    assert _submit(other, "fig99").status_code == 202
    with monkeypatch.context() as planted:       # the reproductions not counted
        planted.setattr(usage, "reproduction_bytes", lambda settings, job_ids=None: 0)
        accepted = _submit(client, "fig99", "full")
        assert accepted.status_code == 202, accepted.text


def test_reproductions_count_in_the_data_folder_s_size(service, monkeypatch):
    """A command line's reproduction of STORED bytes takes the data folder past
    max_data_bytes with the next job's estimate: 507 naming the setting."""
    _, _, store, settings = service()
    _write(default_out_dir(settings, "vt", "fig98"), STORED)
    limit = data_bytes(store, settings) + REPRODUCTION_BYTES - STORED // 2
    client, _, _, _ = service(max_data_bytes=limit)
    refused = _submit(client, "fig99")
    assert refused.status_code == 507 and "max_data_bytes" in refused.json()["detail"], \
        refused.text
    with monkeypatch.context() as planted:       # the reproductions not counted
        planted.setattr(work, "reproduction_bytes", lambda settings, job_ids=None: 0)
        accepted = _submit(client, "fig99")
        assert accepted.status_code == 202, accepted.text
