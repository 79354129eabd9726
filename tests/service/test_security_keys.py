"""Each API key keeps to its own jobs, and work is bounded in time, against a real
`nirc-bench serve` on loopback (on SQLite and PostgreSQL), whose Dask scheduler has
no worker: every job stays queued, nothing renders.

Before: key B canceled key A's job (200); an Idempotency-Key that A had used was
refused to B as "used for a different request"; one key could queue any number of
jobs; a 2^24-spp reference at 8x8 (about 3.3 h on this CPU) and a 1000-eps sweep
(about 1.9 h) were accepted, as they were under the sample limit.
After: cancelling another key's job needs an admin key (403), Idempotency-Keys are
per key, a key holds at most max_jobs_per_key unfinished jobs (429), and a job
estimated past max_job_seconds is refused with its estimate (422).
"""

from __future__ import annotations

import subprocess
import sys

import httpx

from tests.service.live import Scheduler, Service, create_key

SPEC = {"scene": "cornell-box", "method": "pt", "resolution": 8, "spp": 1, "frames": 1,
        "seeds": 1, "reference": {"spp": 64, "spp_per_pass": 8}}


def post(service: Service, key: str, path: str, body: dict, **headers: str) -> httpx.Response:
    return httpx.post(f"{service.url}/api/v1/{path}", json=body, timeout=30,
                      headers={"X-API-Key": key, **headers})


def test_keys_keep_to_their_own_jobs_and_work_is_bounded_in_time(tmp_path, database_url):
    scheduler = Scheduler()
    scheduler.start()
    service = Service(tmp_path / "data", scheduler=scheduler.address,
                      database_url=database_url)
    service.env["NIRC_BENCH_MAX_JOBS_PER_KEY"] = "2"
    a, b = service.key, create_key(service.env)
    admin = subprocess.run([sys.executable, "-m", "service", "apikey", "create", "--admin"],
                           env=service.env, capture_output=True, text=True).stdout.strip()
    try:
        service.start()
        # Idempotency-Keys are per key: B's "k1" is not A's.
        first = post(service, a, "jobs", SPEC, **{"Idempotency-Key": "k1"})
        assert first.status_code == 202, first.text
        other = post(service, b, "jobs", {**SPEC, "frames": 2}, **{"Idempotency-Key": "k1"})
        assert other.status_code == 202, other.text
        assert other.json()["id"] != first.json()["id"]
        again = post(service, a, "jobs", SPEC, **{"Idempotency-Key": "k1"})
        assert again.json()["id"] == first.json()["id"]
        # At most two unfinished jobs per key; another key is not held back.
        second = post(service, a, "jobs", {**SPEC, "frames": 3})
        assert second.status_code == 202, second.text
        third = post(service, a, "jobs", {**SPEC, "frames": 4})
        assert third.status_code == 429 and "max_jobs_per_key" in third.json()["detail"]
        assert int(third.headers["Retry-After"]) > 0
        assert post(service, b, "jobs", {**SPEC, "frames": 4}).status_code == 202
        # Cancelling: the owner or an admin key, nobody else.
        job = first.json()["id"]
        refused = post(service, b, f"jobs/{job}/cancel", {})
        assert refused.status_code == 403 and "admin" in refused.json()["detail"]
        assert service.get(f"/api/v1/jobs/{job}")["status"] == "queued"
        assert post(service, admin, f"jobs/{job}/cancel", {}).json()["status"] == "canceled"
        own = post(service, a, f"jobs/{second.json()['id']}/cancel", {})
        assert own.status_code == 200 and own.json()["status"] == "canceled"
        assert post(service, a, "jobs", {**SPEC, "frames": 4}).status_code == 202
        # Time: under the sample limit, over the time limit (1 h), with the estimate.
        reference = post(service, b, "jobs", {**SPEC, "reference": {"spp": 1 << 24}})
        assert reference.status_code == 422, reference.text
        error = reference.json()["detail"][0]
        assert "max_job_seconds" in error["msg"] and "reference" in error["msg"]
        assert error["ctx"]["estimated_s"] > error["ctx"]["limit_s"] == 3600
        eps = [round(0.001 * (i + 1), 3) for i in range(1000)]
        sweep = post(service, b, "sweeps", {"scene": "cornell-box", "eps": eps, "seeds": 2})
        assert sweep.status_code == 422 and "max_job_seconds" in sweep.text, sweep.text
    finally:
        service.stop()
        scheduler.stop()
