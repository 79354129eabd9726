"""`nirc-bench serve` for real: uvicorn on loopback, the Dask LocalCluster, the isolated
runner — a job submitted over REST completes; killing the whole service mid-job and
starting it again completes the job once (no duplicate result)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

LONG = {"scene": "cornell-box", "method": "pt", "resolution": 16, "spp": 1, "frames": 400,
        "seeds": 2, "reference": {"spp": 64, "spp_per_pass": 8}}
SMALL = {**LONG, "resolution": 8, "frames": 2}


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _env(data_dir: Path) -> dict[str, str]:
    env = {**os.environ, "NIRC_BENCH_DATA_DIR": str(data_dir), "NIRC_BENCH_JOB_LEASE_S": "3"}
    env.pop("NIRC_BENCH_DATABASE_URL", None)
    return env


class Service:
    def __init__(self, data_dir: Path) -> None:
        self.data_dir = data_dir
        self.port = _free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen | None = None

    def start(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "service", "serve", "--port", str(self.port)],
            env=_env(self.data_dir), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            try:
                if httpx.get(f"{self.url}/api/v1/scenes", timeout=2).status_code == 200:
                    return
            except httpx.HTTPError:
                time.sleep(0.3)
        raise AssertionError("the service did not start")

    def kill(self) -> None:
        """SIGKILL the service and everything it started (its Dask workers, renders)."""
        os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait()

    def stop(self) -> None:
        if self.proc and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.kill()


@pytest.fixture
def service(tmp_path):
    data_dir = tmp_path / "data"
    created = subprocess.run([sys.executable, "-m", "service", "apikey", "create", "--name",
                              "test"], env=_env(data_dir), capture_output=True, text=True)
    assert created.returncode == 0, created.stderr
    svc = Service(data_dir)
    svc.key = created.stdout.strip()
    svc.start()
    yield svc
    svc.stop()


def _wait(svc: Service, job_id: int, until, timeout: float = 300) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = httpx.get(f"{svc.url}/api/v1/jobs/{job_id}", timeout=5).json()
        if until(job):
            return job
        time.sleep(0.3)
    raise AssertionError(f"job {job_id}: {job}")


def _submit(svc: Service, spec: dict) -> dict:
    response = httpx.post(f"{svc.url}/api/v1/jobs", json=spec, headers={"X-API-Key": svc.key},
                          timeout=10)
    assert response.status_code == 202, response.text
    return response.json()


def test_a_job_submitted_over_rest_runs_on_the_cluster(service):
    job = _submit(service, SMALL)
    done = _wait(service, job["id"], lambda j: j["status"] in ("succeeded", "failed"))
    assert done["status"] == "succeeded", done
    run = httpx.get(f"{service.url}/api/v1/runs/{done['run_id']}", timeout=5).json()
    assert len(run["per_seed"]) == 2
    assert "://" in done["worker"]   # ran on a Dask worker (inproc:// in the embedded cluster)


def test_killing_the_service_mid_job_then_restarting_completes_it_once(service):
    job = _submit(service, LONG)
    _wait(service, job["id"], lambda j: j["progress"].get("stage", "").startswith("seed"))
    service.kill()
    service.start()
    done = _wait(service, job["id"], lambda j: j["status"] in ("succeeded", "failed"))
    assert done["status"] == "succeeded" and done["attempts"] == 2, done
    runs = httpx.get(f"{service.url}/api/v1/results", timeout=5).json()
    assert [r["id"] for r in runs] == [done["run_id"]]
