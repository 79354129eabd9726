"""`nirc-bench serve` for real: uvicorn on loopback, the Dask LocalCluster (or a
scheduler with separate `nirc-bench worker`s), the isolated runner — a job submitted
over REST completes; killing the whole service, or separately a worker, mid-job
completes the job once after a restart (no duplicate result). On SQLite and PostgreSQL."""

from __future__ import annotations

import pytest

from tests.service.live import Scheduler, Service, Worker

LONG = {"scene": "cornell-box", "method": "pt", "resolution": 16, "spp": 1, "frames": 400,
        "seeds": 2, "reference": {"spp": 64, "spp_per_pass": 8}}
SMALL = {**LONG, "resolution": 8, "frames": 2}


@pytest.fixture
def service(tmp_path, database_url):
    svc = Service(tmp_path / "data", database_url=database_url)
    svc.start()
    yield svc
    svc.stop()


def test_a_job_submitted_over_rest_runs_on_the_cluster(service):
    job = service.submit(SMALL)
    done = service.wait(job["id"])
    assert done["status"] == "succeeded", done
    run = service.get(f"/api/v1/runs/{done['run_id']}")
    assert len(run["per_seed"]) == 2
    assert "://" in done["worker"]   # ran on a Dask worker (inproc:// in the embedded cluster)


def test_killing_the_service_mid_job_then_restarting_completes_it_once(service):
    job = service.submit(LONG)
    service.wait(job["id"], lambda j: j["progress"].get("stage", "").startswith("seed"))
    service.kill()
    service.start()
    done = service.wait(job["id"])
    assert done["status"] == "succeeded" and done["attempts"] == 2, done
    runs = service.get("/api/v1/results")
    assert [r["id"] for r in runs] == [done["run_id"]]


def test_killing_a_worker_mid_job_then_starting_another_completes_it_once(tmp_path,
                                                                          database_url):
    """Scale-out: service, scheduler and workers are separate processes. SIGKILL the
    worker running a job (with its render process); the service keeps serving, the
    scheduler hands the task to a new worker, which takes the job over once the dead
    runner's heartbeat lease expires; one run is stored."""
    data_dir = tmp_path / "data"
    scheduler = Scheduler()
    scheduler.start()
    service = Service(data_dir, scheduler=scheduler.address, database_url=database_url)
    first, second = (Worker(scheduler, data_dir, database_url) for _ in range(2))
    try:
        first.start()
        service.start()
        job = service.submit(LONG)
        running = service.wait(job["id"],
                               lambda j: j["progress"].get("stage", "").startswith("seed"))
        first.kill()
        assert service.alive() and scheduler.alive()
        assert service.get(f"/api/v1/jobs/{job['id']}")["status"] == "running"
        second.start()
        done = service.wait(job["id"])
        assert done["status"] == "succeeded" and done["attempts"] == 2, done
        assert done["worker"] != running["worker"]      # a different Dask worker finished it
        assert [r["id"] for r in service.get("/api/v1/results")] == [done["run_id"]]
    finally:
        for process in (service, first, second, scheduler):
            process.stop()
