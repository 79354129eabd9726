"""GPU workers without a GPU: what can be checked on a CPU machine. Each GPU worker
is its own process pinned to one device (CUDA_VISIBLE_DEVICES) with the Dask
resource GPU=1, CPU workers have CPU=1, and a job runs only on a worker of its device
class with that class's variant — so on this machine a GPU job fails at once with
the CUDA backend's message while CPU jobs keep running; the SLURM batch script starts
the same workers; a service without GPU workers refuses GPU jobs (409)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key
from jobs.execution.dispatch import Dispatcher
from jobs.execution.gpus import GpuError, detect_gpu_count, worker_commands
from jobs.record.config import Settings
from jobs.record.db import open_store
from service.api.main import create_app
from tests.service.live import Process, Scheduler, Service

REPO = Path(__file__).resolve().parents[2]
SLURM_SCRIPT = REPO / "scripts" / "slurm" / "nirc-bench-worker.sbatch"
SMALL = {"scene": "cornell-box", "method": "pt", "resolution": 8, "spp": 1, "frames": 2,
         "seeds": 1, "reference": {"spp": 16, "spp_per_pass": 8}}


def test_worker_commands_pin_one_gpu_each(monkeypatch):
    monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
    ((argv, env),) = worker_commands("tcp://h:1", 0, {"A": "1"})
    assert argv[argv.index("--resources") + 1] == "CPU=1" and env == {"A": "1"}
    assert [env["CUDA_VISIBLE_DEVICES"] for _, env in worker_commands("tcp://h:1", 2, {})] \
        == ["0", "1"]
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "3,5")      # as SLURM or Docker give it
    commands = worker_commands("tcp://h:1", 2, {})
    assert [env["CUDA_VISIBLE_DEVICES"] for _, env in commands] == ["3", "5"]
    assert all(argv[argv.index("--resources") + 1] == "GPU=1" for argv, _ in commands)
    assert detect_gpu_count() == 2
    with pytest.raises(GpuError, match="only 2"):
        worker_commands("tcp://h:1", 3, {})
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "")
    assert detect_gpu_count() == 0


def _worker_devices(address: str, count: int) -> dict[str, tuple[str | None, dict]]:
    """name -> (CUDA_VISIBLE_DEVICES, resources) of the ``count`` workers at ``address``."""
    from distributed import Client

    with Client(address) as client:
        client.wait_for_workers(count, timeout=120)
        visible = client.run(lambda: os.environ.get("CUDA_VISIBLE_DEVICES"))
        workers = client.scheduler_info()["workers"]
        return {info["name"]: (visible[address_], info["resources"])
                for address_, info in workers.items()}


def test_the_slurm_script_starts_one_pinned_worker_per_allocated_gpu():
    bin_dir = Path(sys.executable).parent
    assert (bin_dir / "nirc-bench").is_file()
    scheduler = Scheduler()
    scheduler.start()
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}",
           "NIRC_BENCH_SCHEDULER": scheduler.address, "SLURM_GPUS_ON_NODE": "2",
           "CUDA_VISIBLE_DEVICES": "3,5"}
    job = Process(["bash", str(SLURM_SCRIPT)], env)
    try:
        job.start()
        workers = _worker_devices(scheduler.address, 2)
        assert sorted(workers.values(), key=str) == [("3", {"GPU": 1}), ("5", {"GPU": 1})]
        job.stop()
        assert job.proc.returncode is not None and not job.alive()
    finally:
        job.stop()
        scheduler.stop()
    missing = subprocess.run(["bash", str(SLURM_SCRIPT)], capture_output=True, text=True,
                             env={k: v for k, v in env.items() if k != "NIRC_BENCH_SCHEDULER"})
    assert missing.returncode != 0 and "NIRC_BENCH_SCHEDULER" in missing.stderr


def test_a_gpu_job_runs_only_on_a_gpu_worker_with_the_cuda_variant(tmp_path):
    """The embedded cluster with one (pretended) GPU worker: the GPU job goes to it and
    fails once with the CUDA backend's error (this machine has no GPU), the CPU job
    renders on the CPU worker."""
    service = Service(tmp_path / "data", options=["--gpus", "1"])
    try:
        service.start()
        gpu = service.wait(service.submit(SMALL, device_class="gpu")["id"])
        assert gpu["status"] == "failed" and gpu["attempts"] == 1, gpu
        assert "cuda_ad_rgb" in gpu["error"]
        cpu = service.wait(service.submit(SMALL)["id"])
        assert cpu["status"] == "succeeded", cpu
        assert cpu["worker"] != gpu["worker"]
        assert service.listening() == {"127.0.0.1"}     # the GPU worker too
        run = service.get(f"/api/v1/runs/{cpu['run_id']}")
        assert run["device"]["variant"] == "llvm_ad_rgb"
    finally:
        service.stop()


def test_without_gpu_workers_the_embedded_service_refuses_gpu_jobs(tmp_path, monkeypatch):
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    settings = Settings(data_dir=tmp_path / "data")
    _, key = create_api_key(open_store(settings), "gpu")
    dispatcher = Dispatcher(settings, gpus=0)
    try:
        with TestClient(create_app(settings, dispatcher)) as client:
            response = client.post("/api/v1/jobs?device_class=gpu", json=SMALL,
                                   headers={"X-API-Key": key})
        assert response.status_code == 409
        assert "no GPU worker" in response.json()["detail"]
    finally:
        dispatcher.close()
