"""Real processes for the service tests: `nirc-bench serve` on loopback, a Dask
scheduler, `nirc-bench worker`s — each in its own process group, so a test can
SIGKILL one of them (and everything it started) without touching the others."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import httpx

FINAL = ("succeeded", "failed", "canceled")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def service_env(data_dir: Path, database_url: str | None = None) -> dict[str, str]:
    """The data folder and database (SQLite in it, unless ``database_url``); a short
    heartbeat lease, so a job whose runner was killed is taken over quickly."""
    env = {**os.environ, "NIRC_BENCH_DATA_DIR": str(data_dir), "NIRC_BENCH_JOB_LEASE_S": "3"}
    env.pop("NIRC_BENCH_DATABASE_URL", None)
    if database_url:
        env["NIRC_BENCH_DATABASE_URL"] = database_url
    return env


class Process:
    """A command in its own session; ``kill`` SIGKILLs its whole process group."""

    def __init__(self, args: list[str], env: dict[str, str]) -> None:
        self.args, self.env = args, env
        self.proc: subprocess.Popen | None = None

    def start(self) -> None:
        self.proc = subprocess.Popen(self.args, env=self.env, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, start_new_session=True)

    def listening(self) -> set[str]:
        """The addresses it and its children listen on (TCP)."""
        import psutil

        root = psutil.Process(self.proc.pid)
        return {conn.laddr.ip for process in (root, *root.children(recursive=True))
                for conn in process.net_connections(kind="tcp")
                if conn.status == psutil.CONN_LISTEN}

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def kill(self) -> None:
        os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait()

    def stop(self) -> None:
        if self.alive():
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.kill()


def create_key(env: dict[str, str]) -> str:
    """An API key in the database of ``env`` (service_env), made in this process as
    `nirc-bench apikey create` makes it: starting the CLI for it cost ~2.4 s of CPU
    (its imports), for every service a test starts."""
    from jobs.execution.apikeys import create_api_key
    from jobs.record.config import Settings
    from jobs.record.db import open_store

    store = open_store(Settings(data_dir=Path(env["NIRC_BENCH_DATA_DIR"]),
                                database_url=env.get("NIRC_BENCH_DATABASE_URL")))
    try:
        return create_api_key(store, "test")[1]
    finally:
        store.close()


class Service(Process):
    """`nirc-bench serve` (embedded LocalCluster, or ``scheduler``) on a loopback port."""

    def __init__(self, data_dir: Path, scheduler: str | None = None,
                 database_url: str | None = None, options: Sequence[str] = ()) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        args = [sys.executable, "-m", "service", "serve", "--port", str(self.port), *options]
        super().__init__(args + (["--scheduler", scheduler] if scheduler else []),
                         service_env(data_dir, database_url))
        self.key = create_key(self.env)

    def start(self) -> None:
        super().start()
        self.wait_until_serving()

    def wait_until_serving(self) -> None:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            try:
                if httpx.get(f"{self.url}/api/v1/scenes", timeout=2).status_code == 200:
                    return
            except httpx.HTTPError:
                time.sleep(0.3)
        raise AssertionError("the service did not start")

    def submit(self, spec: dict, kind: str = "jobs", device_class: str = "cpu") -> dict:
        response = httpx.post(f"{self.url}/api/v1/{kind}?device_class={device_class}",
                              json=spec, headers={"X-API-Key": self.key}, timeout=10)
        assert response.status_code == 202, response.text
        return response.json()

    def get(self, path: str) -> dict | list:
        response = httpx.get(f"{self.url}{path}", timeout=10)
        assert response.status_code == 200, response.text
        return response.json()

    def wait(self, job_id: int, until: Callable[[dict], bool] = lambda j: j["status"] in FINAL,
             timeout: float = 300) -> dict:
        deadline = time.monotonic() + timeout
        job: dict = {}
        while time.monotonic() < deadline:
            job = self.get(f"/api/v1/jobs/{job_id}")
            if until(job):
                return job
            time.sleep(0.3)
        raise AssertionError(f"job {job_id} timed out: {job}")


def start_together(*services: Service) -> None:
    """Start ``services`` at once, then wait until each serves: their start-ups (imports,
    Dask clients) overlap instead of adding up."""
    for service in services:
        Process.start(service)
    for service in services:
        service.wait_until_serving()


def stop_together(*processes: Process) -> None:
    """Ask ``processes`` to stop at once (SIGTERM), then wait for each (killing one that
    does not stop)."""
    for process in processes:
        if process.alive():
            os.killpg(process.proc.pid, signal.SIGTERM)
    for process in processes:
        process.stop()


class Scheduler(Process):
    """A Dask scheduler on a loopback port (no dashboard)."""

    def __init__(self) -> None:
        port = free_port()
        self.address = f"tcp://127.0.0.1:{port}"
        super().__init__([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host",
                          "127.0.0.1", "--port", str(port), "--no-dashboard"], dict(os.environ))

    def start(self) -> None:
        super().start()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            with socket.socket() as sock:
                if sock.connect_ex(("127.0.0.1", int(self.address.rsplit(":", 1)[1]))) == 0:
                    return
            time.sleep(0.2)
        raise AssertionError("the Dask scheduler did not start")


class Worker(Process):
    """`nirc-bench worker --scheduler ...` (a Dask worker with its nanny)."""

    def __init__(self, scheduler: Scheduler, data_dir: Path,
                 database_url: str | None = None) -> None:
        super().__init__([sys.executable, "-m", "service", "worker", "--scheduler",
                          scheduler.address], service_env(data_dir, database_url))
