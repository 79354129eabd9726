"""Hand queued jobs to Dask distributed workers.

Embedded default: a ``LocalCluster`` inside the service process, one worker
with one thread on a CPU machine (a render uses every core; two at once would
only slow each other and spoil their timings). The worker itself only claims
jobs and watches their render processes, so it needs no process of its own. Scale-out: ``nirc-bench serve
--scheduler tcp://HOST:8786`` connects to a running scheduler, and each GPU
machine runs ``nirc-bench worker --scheduler ... --gpus N``, whose workers
advertise the resource ``GPU=1``; GPU jobs ask for it. On SLURM, dask-jobqueue's
``SLURMCluster`` starts such workers as batch jobs (README).

A Dask task only calls :func:`jobs.runner.run_job`, which claims the job in
the database, so a task that Dask runs twice (a worker lost mid-task) cannot
run a job twice: the second claim finds it running or finished.
"""

from __future__ import annotations

import socket
from typing import Any

from jobs.config import Settings
from jobs.models import Job


def run_job_task(job_id: int, settings_json: dict[str, Any], timeout_s: float | None) -> str:
    """The Dask task: run one job (in its own child process) and return its status."""
    from distributed import get_worker

    from jobs.runner import run_job

    try:
        worker = get_worker().address
    except ValueError:  # run outside a worker (tests)
        worker = socket.gethostname()
    return run_job(job_id, Settings(**settings_json), worker=worker, timeout_s=timeout_s)


class Dispatcher:
    """Submits job ids to a Dask cluster (embedded ``LocalCluster`` or a scheduler)."""

    def __init__(self, settings: Settings, scheduler: str | None = None,
                 timeout_s: float | None = None) -> None:
        import dask
        from distributed import Client, LocalCluster

        self.settings = settings
        self.timeout_s = timeout_s
        self.cluster = None
        # Dask's statistical profiler samples every worker thread 100 times a second:
        # on a 2-core machine that steals measurable time from the render process.
        dask.config.set({"distributed.worker.profile.enabled": False})
        if scheduler:
            self.client = Client(scheduler)
        else:
            # The worker runs in this process: it only claims jobs and watches their
            # render processes, which provide the isolation (jobs.runner).
            self.cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                        dashboard_address=None)
            self.client = Client(self.cluster)

    def submit(self, job: Job) -> None:
        """Run ``job`` on a worker (GPU jobs on a worker with the GPU resource)."""
        from distributed import fire_and_forget

        resources = {"GPU": 1} if job.device_class == "gpu" else None
        future = self.client.submit(
            run_job_task, job.id, self.settings.model_dump(mode="json"), self.timeout_s,
            key=f"nirc-job-{job.id}-{job.attempts}", pure=False, resources=resources)
        fire_and_forget(future)

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()
