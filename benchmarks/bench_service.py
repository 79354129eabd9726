"""Benchmark: the service's overhead over a direct render, and its submission rate.

1. The same small render job called directly (``jobs.executor.execute`` in this
   process) and submitted through REST -> database queue -> Dask worker ->
   render process (``nirc-bench serve`` on loopback, embedded LocalCluster),
   wall time from submission to the job's final status (polled every 100 ms).
   Both after a warm-up job with the same kernels (reference rendered, JIT
   compiled, the render process started): the warm-up's extra time is the
   fixed start-up, reported separately. Goal (issue 5): ratio <= 1.05.
2. Submission throughput: jobs per second accepted (202) by the API from 16
   concurrent clients.
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime
from pathlib import Path
from statistics import median

import httpx

SPEC = {"scene": "cornell-box", "method": "pt", "resolution": 128, "spp": 1, "frames": 32,
        "seeds": 4, "reference": {"spp": 1024}}


def _direct(data_dir: Path, repeats: int) -> tuple[float, list[float]]:
    from jobs.config import Settings
    from jobs.db import open_store
    from jobs.executor import execute
    from jobs.spec import RenderSpec

    settings = Settings(data_dir=data_dir)
    store = open_store(settings)
    times = []
    for i in range(repeats + 1):
        start = time.perf_counter()
        execute(RenderSpec(**{**SPEC, "eps": 0.01 + i * 1e-6}), store, settings)
        times.append(time.perf_counter() - start)
    return times[0], times[1:]


def _service(data_dir: Path, repeats: int, n_submit: int) -> tuple[float, list[float], float]:
    env = {**os.environ, "NIRC_BENCH_DATA_DIR": str(data_dir)}
    env.pop("NIRC_BENCH_DATABASE_URL", None)
    key = subprocess.run([sys.executable, "-m", "service", "apikey", "create"], env=env,
                         capture_output=True, text=True, check=True).stdout.strip()
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    url = f"http://127.0.0.1:{port}"
    server = subprocess.Popen([sys.executable, "-m", "service", "serve", "--port", str(port)],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)
    client = httpx.Client(base_url=url, headers={"X-API-Key": key}, timeout=30)
    breakdown: list[tuple[float, float]] = []
    try:
        while True:
            try:
                client.get("/api/v1/scenes")
                break
            except httpx.HTTPError:
                time.sleep(0.2)

        def run(spec: dict) -> float:
            start = time.perf_counter()
            job = client.post("/api/v1/jobs", json=spec).json()
            while job["status"] not in ("succeeded", "failed", "canceled"):
                time.sleep(0.1)
                job = client.get(f"/api/v1/jobs/{job['id']}").json()
            assert job["status"] == "succeeded", job
            wall = time.perf_counter() - start
            stamps = {k: datetime.fromisoformat(job[k]) for k in
                      ("created_at", "started_at", "finished_at")}
            breakdown.append(((stamps["started_at"] - stamps["created_at"]).total_seconds(),
                              (stamps["finished_at"] - stamps["started_at"]).total_seconds()))
            return wall

        times = [run({**SPEC, "eps": 0.01 + i * 1e-6}) for i in range(repeats + 1)]
        tiny = {**SPEC, "resolution": 4, "frames": 1, "seeds": 1, "reference": {"spp": 8}}
        start = time.perf_counter()
        with ThreadPoolExecutor(16) as pool:
            codes = list(pool.map(
                lambda i: client.post("/api/v1/jobs", json={**tiny, "eps": 0.02 + i * 1e-6})
                .status_code, range(n_submit)))
        rate = n_submit / (time.perf_counter() - start)
        assert codes == [202] * n_submit
        queued = median(b[0] for b in breakdown[1:])
        running = median(b[1] for b in breakdown[1:])
        print(f"  service job: submitted -> claimed {queued:.3f} s, claimed -> done {running:.3f} s")
        return times[0], times[1:], rate
    finally:
        client.close()
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--submit", type=int, default=200)
    args = parser.parse_args()
    from renderers.backend import device_info, init_backend

    init_backend()
    with tempfile.TemporaryDirectory() as folder:
        direct_first, direct = _direct(Path(folder) / "direct", args.repeats)
        service_first, service, rate = _service(Path(folder) / "service", args.repeats,
                                                args.submit)
    d, s = median(direct), median(service)
    print(f"device: {device_info()['device_key']}  job: pt, cornell-box 128x128, 32 frames x "
          f"4 seeds; median of {args.repeats}")
    print(f"  direct (executor in process)        {d:7.3f} s   (first, with compile: "
          f"{direct_first:.2f} s)")
    print(f"  REST + queue + worker + render proc {s:7.3f} s   (first: {service_first:.2f} s)")
    print(f"service / direct: {s / d:.3f}  (goal <= 1.05; +{s - d:.3f} s per job); fixed "
          f"start-up of the first service job over the first direct one: "
          f"{service_first - direct_first:+.2f} s")
    print(f"submission throughput: {rate:.0f} jobs/s accepted (16 concurrent clients)")


if __name__ == "__main__":
    main()
