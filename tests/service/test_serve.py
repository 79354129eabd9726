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
SWEEP = {"scene": "cornell-box", "eps": [0.3, 1.0], "nc": [1, 2], "resolution": 12, "seeds": 2,
         "train_frames": 3, "v1_spp": 16, "reference": {"spp": 64},
         "params": {"cache": {"batch_size": 1024}, "min_train_paths": 1024},
         "allow_loaded": True}  # equal-time probes count on the shared, loaded test machine


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
    assert service.listening() == {"127.0.0.1"}     # nothing of Dask's on other interfaces


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


def _serving_health(workers: list[Worker]) -> list[int]:
    """The ports of ``workers``' processes that answer Dask's ``/health`` page."""
    import httpx
    import psutil

    ports = {conn.laddr.port for worker in workers
             for process in (psutil.Process(worker.proc.pid),
                             *psutil.Process(worker.proc.pid).children(recursive=True))
             for conn in process.net_connections(kind="tcp") if conn.status == psutil.CONN_LISTEN}
    serving = []
    for port in ports:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/health", timeout=2).status_code == 200:
                serving.append(port)
        except httpx.HTTPError:         # a Dask comm port, not HTTP
            pass
    return serving


def test_a_sweeps_independent_stages_run_on_different_workers_at_once(tmp_path):
    """Scale-out: with two workers, the caches of a sweep train at the same time (the
    task graph lets them: each needs only the reference)."""
    from distributed import Client

    data_dir = tmp_path / "data"
    scheduler = Scheduler()
    scheduler.start()
    service = Service(data_dir, scheduler=scheduler.address)
    workers = [Worker(scheduler, data_dir) for _ in range(2)]
    try:
        for worker in workers:
            worker.start()
        with Client(scheduler.address) as client:
            client.wait_for_workers(2, timeout=120)
        assert not _serving_health(workers), "a scale-out worker serves Dask's HTTP pages"
        service.start()
        # Caches that train for seconds, not for the fraction of a second that warm
        # render processes need for 3 frames: long enough to overlap if both run. One
        # method: its two caches (one per seed) are two stages that may run at once.
        job = service.submit({**SWEEP, "train_frames": 40, "methods": ["nirc"]}, kind="sweeps")
        assert service.wait(job["id"], timeout=600)["status"] == "succeeded"
        stages = [j for j in service.get("/api/v1/jobs?limit=100") if j["parent_id"] == job["id"]]
        assert {j["status"] for j in stages} == {"succeeded"}
        caches = [j for j in stages if " cache " in j["spec"]["name"]]
        overlapping = [(a["spec"]["name"], b["spec"]["name"]) for a in caches for b in caches
                       if a["worker"] != b["worker"]
                       and a["started_at"] < b["finished_at"] and b["started_at"] < a["finished_at"]]
        assert overlapping, [(j["spec"]["name"], j["worker"], j["started_at"], j["finished_at"])
                             for j in caches]
    finally:
        for process in (service, *workers, scheduler):
            process.stop()
