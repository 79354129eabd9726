"""GPU workers: one Dask worker process per GPU, each seeing only its own device.

A worker advertises the Dask resource ``GPU=1`` (GPU jobs ask for it) and runs
with ``CUDA_VISIBLE_DEVICES`` set to its one device, so it and every render
process it starts use that GPU and no other: N workers on a host with N GPUs
render on N devices, never all on device 0 (which is where Dr.Jit's CUDA backend
would put each of them otherwise). The device ids are taken from the
``CUDA_VISIBLE_DEVICES`` the host gives us (SLURM, the container runtime), or
``0 .. N-1``.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
from typing import Any

#: The Dask resources of a CPU worker and of a GPU worker; a job asks for one of them
#: by its device class, so a CPU job never shares a GPU worker's host CPU time with
#: the CPU worker's render, and a GPU job runs only where a GPU is.
CPU_WORKER = {"CPU": 1}
GPU_WORKER = {"GPU": 1}


class GpuError(ValueError):
    """More GPU workers were asked for than the host makes visible."""


def visible_gpus() -> list[str] | None:
    """The devices ``CUDA_VISIBLE_DEVICES`` allows, or None if it is not set."""
    value = os.environ.get("CUDA_VISIBLE_DEVICES")
    if value is None:
        return None
    return [device.strip() for device in value.split(",") if device.strip()]


def detect_gpu_count() -> int:
    """GPUs on this host: as many as ``CUDA_VISIBLE_DEVICES`` names, else the lines
    of ``nvidia-smi -L``; 0 without an NVIDIA driver."""
    visible = visible_gpus()
    if visible is not None:
        return len(visible)
    nvidia_smi = shutil.which("nvidia-smi")
    if nvidia_smi is None:
        return 0
    try:
        listing = subprocess.run([nvidia_smi, "-L"], capture_output=True, text=True,
                                 timeout=30, check=True).stdout
    except (OSError, subprocess.SubprocessError):
        return 0
    return sum(line.startswith("GPU ") for line in listing.splitlines())


def gpu_devices(count: int) -> list[str]:
    """The device ids of ``count`` GPU workers on this host."""
    visible = visible_gpus()
    devices = visible if visible is not None else [str(i) for i in range(count)]
    if count > len(devices):
        raise GpuError(f"{count} GPU workers asked for, but CUDA_VISIBLE_DEVICES allows "
                       f"only {len(devices)} ({','.join(devices) or 'none'})")
    return devices[:count]


def worker_commands(scheduler: str, gpus: int,
                    env: dict[str, str]) -> list[tuple[list[str], dict[str, str]]]:
    """(argv, environment) of this host's Dask workers for ``scheduler``: one CPU
    worker if ``gpus`` is 0, else one per GPU, pinned to it (module doc)."""
    base = [sys.executable, "-m", "distributed.cli.dask_worker", scheduler,
            "--nthreads", "1", "--no-dashboard"]
    if gpus == 0:
        return [([*base, "--resources", _resources(CPU_WORKER)], env)]
    host = socket.gethostname()
    return [([*base, "--resources", _resources(GPU_WORKER), "--name", f"{host}-gpu{device}"],
             {**env, "CUDA_VISIBLE_DEVICES": device})
            for device in gpu_devices(gpus)]


def _resources(resources: dict[str, int]) -> str:
    """``dask worker --resources`` syntax."""
    return " ".join(f"{name}={count}" for name, count in resources.items())


def start_gpu_workers(scheduler: str, gpus: int, env: dict[str, str],
                      dashboard: bool = False) -> list[Any]:
    """Start ``gpus`` pinned GPU worker processes for the embedded cluster. Each is a
    single process (no nanny: the render process is the isolation) on loopback,
    killed with the service, so a killed service leaves no worker behind; with its
    Dask dashboard if ``dashboard`` (its HTTP server, on loopback either way, is
    closed by the dispatcher otherwise)."""
    from jobs.execution.runner import die_with_parent

    if gpus == 0:
        return []
    loopback = ["--host", "127.0.0.1", "--dashboard-address", "127.0.0.1:0",
                *(["--dashboard"] if dashboard else [])]
    return [subprocess.Popen([*argv, "--no-nanny", *loopback], env=worker_env,
                             preexec_fn=die_with_parent)
            for argv, worker_env in worker_commands(scheduler, gpus, env)]


def run_workers(commands: list[tuple[list[str], dict[str, str]]]) -> int:
    """Run the worker processes until one exits (or this process is told to stop),
    then stop the others; returns the first exit status."""
    processes = [subprocess.Popen(argv, env=env) for argv, env in commands]

    def stop(signum: int, frame: Any) -> None:
        for process in processes:
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    _, status = os.wait()
    stop(signal.SIGTERM, None)
    for process in processes:
        process.wait()
    return os.waitstatus_to_exitcode(status)
