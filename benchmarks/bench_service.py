"""Benchmark: the service's overhead over a direct render, and its submission rate.

1. The same small render job called directly (``jobs.protocol.executor.execute`` in this
   process) and submitted through REST -> database queue -> Dask worker ->
   render process (``nirc-bench serve`` on loopback, embedded LocalCluster),
   wall time from submission to the job's final status (a long poll: the
   service re-reads the job every 100 ms and answers when it is final).
   Both after a warm-up job with the same kernels (reference rendered, JIT
   compiled, the render process started): the warm-up's extra time is the
   fixed start-up, reported separately. Direct and service runs alternate, so
   a drift of this VM's speed hits both alike; the ratio is the median of the
   paired ratios, with a bootstrap 95 % interval. CPU time per job is split
   into the render process and the service process (API, queue, Dask).
   Goal: ratio <= 1.05.
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


def _cpu_s(process) -> float:
    times = process.cpu_times()
    return times.user + times.system


class _Direct:
    """The job called directly (``jobs.protocol.executor.execute`` in this process)."""

    def __init__(self, data_dir: Path) -> None:
        from jobs.record.config import Settings
        from jobs.record.db import open_store

        self.settings = Settings(data_dir=data_dir)
        self.store = open_store(self.settings)

    def run(self, spec: dict) -> tuple[float, float]:
        """(wall s, CPU s of this process)."""
        import psutil

        from jobs.protocol.executor import execute
        from jobs.protocol.job import RenderJob

        me = psutil.Process()
        cpu, start = _cpu_s(me), time.perf_counter()
        execute(RenderJob.parse(spec), self.store, self.settings)
        return time.perf_counter() - start, _cpu_s(me) - cpu


class _Service:
    """``nirc-bench serve`` on loopback; a job is timed from its POST until its long
    poll returns it final."""

    def __init__(self, data_dir: Path) -> None:
        import psutil

        env = {**os.environ, "NIRC_BENCH_DATA_DIR": str(data_dir)}
        env.pop("NIRC_BENCH_DATABASE_URL", None)
        key = subprocess.run([sys.executable, "-m", "service", "apikey", "create"], env=env,
                             capture_output=True, text=True, check=True).stdout.strip()
        with socket.socket() as sock:
            sock.bind(("127.0.0.1", 0))
            port = sock.getsockname()[1]
        self.server = subprocess.Popen(
            [sys.executable, "-m", "service", "serve", "--port", str(port)], env=env,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        self.process = psutil.Process(self.server.pid)
        self.client = httpx.Client(base_url=f"http://127.0.0.1:{port}",
                                   headers={"X-API-Key": key}, timeout=30)
        while True:
            try:
                self.client.get("/api/v1/scenes")
                break
            except httpx.HTTPError:
                time.sleep(0.2)
        self.breakdown: list[tuple[float, float]] = []

    def run(self, spec: dict) -> tuple[float, float, float]:
        """(wall s, CPU s of the service process, CPU s of its render processes)."""
        children = self.process.children(recursive=True)
        service_cpu = _cpu_s(self.process)
        render_cpu = {child.pid: _cpu_s(child) for child in children}
        start = time.perf_counter()
        job = self.client.post("/api/v1/jobs", json=spec).json()
        while job["status"] not in ("succeeded", "failed", "canceled"):
            job = self.client.get(f"/api/v1/jobs/{job['id']}?wait_s=20").json()
        wall = time.perf_counter() - start
        assert job["status"] == "succeeded", job
        stamps = {k: datetime.fromisoformat(job[k])
                  for k in ("created_at", "started_at", "finished_at")}
        self.breakdown.append(((stamps["started_at"] - stamps["created_at"]).total_seconds(),
                               (stamps["finished_at"] - stamps["started_at"]).total_seconds()))
        render = sum(_cpu_s(child) - render_cpu.get(child.pid, 0.0)
                     for child in self.process.children(recursive=True))
        return wall, _cpu_s(self.process) - service_cpu, render

    def submission_rate(self, n_submit: int) -> float:
        tiny = {**SPEC, "resolution": 4, "frames": 1, "seeds": 1, "reference": {"spp": 8}}
        start = time.perf_counter()
        with ThreadPoolExecutor(16) as pool:
            codes = list(pool.map(
                lambda i: self.client.post("/api/v1/jobs", json={**tiny, "eps": 0.02 + i * 1e-6})
                .status_code, range(n_submit)))
        assert codes == [202] * n_submit
        return n_submit / (time.perf_counter() - start)

    def close(self) -> None:
        self.client.close()
        os.killpg(self.server.pid, signal.SIGTERM)
        self.server.wait(timeout=30)


def _median_ci95(values: list[float], resamples: int = 10_000) -> tuple[float, float]:
    """Percentile-bootstrap 95 % interval of the median of ``values``: this VM's speed
    drifts by several per cent between runs, so the ratio needs its confidence."""
    import numpy as np

    rng = np.random.default_rng(0)
    samples = rng.choice(np.asarray(values), size=(resamples, len(values)))
    low, high = np.percentile(np.median(samples, axis=1), [2.5, 97.5])
    return float(low), float(high)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--submit", type=int, default=200)
    args = parser.parse_args()
    from renderers.backend import device_info, init_backend

    init_backend()
    with tempfile.TemporaryDirectory() as folder:
        direct, service = _Direct(Path(folder) / "direct"), _Service(Path(folder) / "service")
        try:
            specs = [{**SPEC, "eps": 0.01 + i * 1e-6} for i in range(args.repeats + 1)]
            direct_first, service_first = direct.run(specs[0]), service.run(specs[0])
            pairs = [(direct.run(spec), service.run(spec)) for spec in specs[1:]]
            rate = service.submission_rate(args.submit)
        finally:
            service.close()
    d = median(p[0][0] for p in pairs)
    s = median(p[1][0] for p in pairs)
    ratios = [p[1][0] / p[0][0] for p in pairs]
    paired = median(ratios)
    low, high = _median_ci95(ratios)
    print(f"device: {device_info()['device_key']}  job: pt, cornell-box 128x128, 32 frames x "
          f"4 seeds; {args.repeats} pairs, direct and service runs interleaved")
    print(f"  direct (executor in process)        {d:7.3f} s   (first, with compile: "
          f"{direct_first[0]:.2f} s)")
    print(f"  REST + queue + worker + render proc {s:7.3f} s   (first: {service_first[0]:.2f} s)")
    queued = median(b[0] for b in service.breakdown[1:])
    running = median(b[1] for b in service.breakdown[1:])
    print(f"  service job: submitted -> claimed {queued:.3f} s, claimed -> done {running:.3f} s")
    print(f"  CPU per job: direct {median(p[0][1] for p in pairs):.2f} s; render process "
          f"{median(p[1][2] for p in pairs):.2f} s + service process (API, queue, Dask) "
          f"{median(p[1][1] for p in pairs):.3f} s")
    print(f"service / direct: {paired:.3f} [95% CI {low:.3f}, {high:.3f}] (median of "
          f"{len(ratios)} paired ratios, from {min(ratios):.3f} to {max(ratios):.3f}; of "
          f"medians {s / d:.3f}; goal <= 1.05; {s - d:+.3f} s per job); fixed start-up of the "
          f"first service job over the first direct one: "
          f"{service_first[0] - direct_first[0]:+.2f} s")
    print(f"submission throughput: {rate:.0f} jobs/s accepted (16 concurrent clients)")


if __name__ == "__main__":
    main()
