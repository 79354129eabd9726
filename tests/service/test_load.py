"""Load: 500 jobs submitted concurrently over the API are all persisted, and each
completes exactly once (one attempt, one stored run), run by two runner threads;
on SQLite and PostgreSQL."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key
from jobs.execution.queue import JobQueue
from jobs.execution.runner import run_job
from jobs.record.config import Settings
from jobs.record.db import open_store
from service.api.main import create_app

N_JOBS = 500
# Tiny renders that differ only in the metric epsilon: same kernels, same reference.
SPEC = {"scene": "cornell-box", "method": "pt", "resolution": 4, "spp": 1, "frames": 1,
        "seeds": 1, "reference": {"spp": 8, "spp_per_pass": 8}}


class PoolDispatcher:
    """Two runner threads, each with its own render process (as two Dask threads)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.pool = ThreadPoolExecutor(2)
        self.futures = []

    def unavailable(self, device_class: str) -> None:
        return None

    def submit(self, job) -> None:
        self.futures.append(self.pool.submit(run_job, job.id, self.settings, worker="pool"))

    def recover(self, jobs=None) -> list[int]:
        return []       # nothing is stranded in these tests

    def recover_every(self, interval_s: float) -> threading.Event:
        return threading.Event()


def test_500_concurrent_submissions_complete_exactly_once(tmp_path, monkeypatch, database_url):
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    settings = Settings(data_dir=tmp_path / "data", database_url=database_url,
                        max_jobs_per_key=None)   # one key submits all 500
    store = open_store(settings)
    _, key = create_api_key(store, "load")
    dispatcher = PoolDispatcher(settings)
    with TestClient(create_app(settings, dispatcher)) as client:
        client.headers["X-API-Key"] = key

        def submit(i: int) -> int:
            response = client.post("/api/v1/jobs", json={**SPEC, "eps": 0.01 + i * 1e-6})
            assert response.status_code == 202, response.text
            return response.json()["id"]

        start = time.perf_counter()
        with ThreadPoolExecutor(16) as submitters:
            ids = list(submitters.map(submit, range(N_JOBS)))
        accepted_s = time.perf_counter() - start
        assert len(set(ids)) == N_JOBS                  # every submission is its own job
        statuses = [future.result(timeout=900) for future in dispatcher.futures]
    jobs = JobQueue(store).list(limit=10 * N_JOBS)
    failed = [(j.id, j.error) for j in jobs if j.status != "succeeded"]
    assert statuses == ["succeeded"] * N_JOBS, failed[:5]
    assert len(jobs) == N_JOBS and all(j.attempts == 1 for j in jobs)
    runs = store.list_runs(limit=10 * N_JOBS)
    assert sorted(r.idempotency_key for r in runs) == sorted(f"job-{i}" for i in ids)
    assert sorted(j.run_id for j in jobs) == sorted(r.id for r in runs)
    print(f"accepted {N_JOBS} jobs in {accepted_s:.1f} s ({N_JOBS / accepted_s:.0f}/s)")
    store.close()

