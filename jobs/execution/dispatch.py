"""Hand queued jobs to Dask distributed workers.

Embedded default: a ``LocalCluster`` inside the service process, one worker
with one thread for CPU jobs (a render uses every core; two at once would only
slow each other and spoil their timings). That worker only claims jobs and
watches their render processes, so it needs no process of its own. On a
machine with GPUs the embedded cluster adds one worker process per GPU, pinned
to it (jobs/execution/gpus.py). Scale-out: ``nirc-bench serve --scheduler
tcp://HOST:8786`` connects to a running scheduler; machines run ``nirc-bench
worker --scheduler ...`` (one CPU worker) or ``... --gpus N`` (N GPU workers).
CPU workers advertise the Dask resource ``CPU=1`` and GPU workers ``GPU=1``;
every job asks for the one of its device class. On SLURM the same command runs
as a batch job (scripts/slurm/nirc-bench-worker.sbatch, README).

Scale-out connections are TLS with certificates (``tls://`` addresses and the
service's ``tls_*`` settings as a :class:`SchedulerTLS`, see
:func:`scheduler_security`): a Dask scheduler runs any code its clients send on its
workers, so only holders of a certificate signed by the deployment's CA may connect.
The embedded cluster never leaves loopback, and its scheduler and workers serve no
HTTP (Dask's dashboards, info pages, health, metrics) unless ``serve --dask-dashboard``
asks for them (:func:`close_dashboards`).

A Dask task only calls :func:`jobs.execution.runner.run_job`, which claims the job in
the database, so a task that Dask runs twice (a worker lost mid-task) cannot
run a job twice: the second claim finds it running or finished.

Nothing is left stranded: :meth:`Dispatcher.recover` (at start, then every
``redispatch_interval_s`` from the service, and for a job that a new submission
finds as its duplicate) submits again every job that nothing runs — a queued job
whose task has ended (its claim met a full disk or a locked database, or its key
was at its running limit) and a running job whose lease expired (its runner died
or gave it up). The dispatcher remembers its own tasks, so a job whose task is
still waiting for a worker is not submitted twice.

A sweep is submitted as its task graph (jobs/execution/graph.py): one task per stage job,
each depending on the tasks of the stages it needs, and the sweep job's own
task last. A task receives the final statuses of its upstream tasks; a failed
stage fails everything downstream of it (jobs.execution.runner.run_job).
"""

from __future__ import annotations

import logging
import os
import socket
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from jobs.execution.gpus import (
    CPU_WORKER,
    GPU_WORKER,
    detect_gpu_count,
    gpu_devices,
    start_gpu_workers,
)
from jobs.execution.graph import final_stages
from jobs.execution.queue import JobQueue
from jobs.execution.queued import job_of
from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.record.models import Job
from jobs.record.storage import storage_failure

log = logging.getLogger(__name__)

#: Dask settings of every worker (and of the embedded cluster): Dask's defaults wake
#: its event loop many times a second (an event-loop health tick every 20 ms, a memory
#: probe every 100 ms, a system monitor every 500 ms, a profiler sampling worker
#: threads 100 times a second). The service idled at ~5 % of a core with them, which
#: on a 2-core machine is taken from the renders (benchmarks/bench_service.py); a
#: worker here only waits on its render process, so slower housekeeping costs nothing.
QUIET_WORKER_CONFIG = {
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.memory.monitor-interval": "2s",
    "distributed.worker.profile.enabled": False,
}


def dask_environment(config: dict[str, Any]) -> dict[str, str]:
    """``config`` as the DASK_* environment variables a Dask process reads at start."""
    return {"DASK_" + key.upper().replace(".", "__").replace("-", "_"): str(value)
            for key, value in config.items()}


@dataclass(frozen=True)
class SchedulerTLS:
    """The PEM files of mutual TLS with a scheduler: the CA that signed the scheduler's
    and workers' certificates, and this process's own certificate and private key."""

    ca_file: Path
    cert: Path | None
    key: Path | None


def scheduler_security(tls: SchedulerTLS | None, address: str) -> Any:
    """The Dask ``Security`` of a client of the scheduler at ``address``: mutual TLS for
    ``tls://`` (the CA, this process's certificate and key from ``tls``; a peer
    without a certificate of that CA is refused), None for other addresses."""
    from distributed.security import Security

    if not address.startswith("tls://"):
        return None
    if tls is None:
        raise ValueError(f"the scheduler {address} needs TLS files (CA, certificate, key)")
    return Security(tls_ca_file=str(tls.ca_file), tls_client_cert=str(tls.cert),
                    tls_client_key=str(tls.key), require_encryption=True)


def worker_tls_options(tls: SchedulerTLS | None) -> list[str]:
    """``dask worker`` options giving it the same CA, certificate and key."""
    if tls is None:
        return []
    return ["--tls-ca-file", str(tls.ca_file), "--tls-cert", str(tls.cert),
            "--tls-key", str(tls.key)]


def run_job_task(job_id: int, settings_json: dict[str, Any], timeout_s: float | None,
                 *upstream: str) -> str:
    """The Dask task: run one job (in its own child process) and return its status;
    ``upstream``: the statuses of the tasks it depends on."""
    from distributed import get_worker

    from jobs.execution.runner import run_job

    try:
        worker = get_worker().address
    except ValueError:  # run outside a worker (tests)
        worker = socket.gethostname()
    return run_job(job_id, Settings(**settings_json), worker=worker, timeout_s=timeout_s,
                   upstream=upstream)


def close_dashboards(client: Any) -> None:
    """Stop the HTTP servers of ``client``'s scheduler and workers. Dask starts one in
    each, with or without its dashboard, serving unauthenticated pages about the
    cluster (workers, tasks, their logs and call stacks), health and metrics to any
    local account; the embedded cluster needs none of them (its workers and scheduler
    talk over their own connections)."""
    client.run_on_scheduler(_stop_scheduler_http)
    client.run(_stop_worker_http)


def _stop_scheduler_http(dask_scheduler: Any) -> None:
    dask_scheduler.http_server.stop()


def _stop_worker_http(dask_worker: Any) -> None:
    dask_worker.http_server.stop()


class Dispatcher:
    """Submits job ids to a Dask cluster (embedded ``LocalCluster`` or a scheduler)."""

    def __init__(self, settings: Settings, scheduler: str | None = None,
                 timeout_s: float | None = None, gpus: int | None = None,
                 tls: SchedulerTLS | None = None, dashboard: bool = False) -> None:
        """``gpus``: GPU workers of the embedded cluster (None: one per GPU found);
        ``tls``: the files of a ``tls://`` ``scheduler``'s connection; ``dashboard``:
        keep the embedded cluster's Dask dashboards (:func:`close_dashboards`)."""
        import dask
        from distributed import Client, LocalCluster

        self.settings = settings
        self.timeout_s = timeout_s
        self.queue = JobQueue(open_store(settings))
        # job id -> the future of its (last) task; submissions come from request
        # threads and the recovery timer.
        self._tasks: dict[int, Any] = {}
        self._lock = threading.Lock()
        self._dispatches = 0
        self.cluster = None
        self.gpu_workers: list[Any] = []
        self.dashboard = dashboard
        dask.config.set(QUIET_WORKER_CONFIG)
        if scheduler:
            self.client = Client(scheduler, security=scheduler_security(tls, scheduler))
            return
        gpus = detect_gpu_count() if gpus is None else gpus
        gpu_devices(gpus)       # fail now, not in the workers, if they are not there
        # The CPU worker runs in this process: it only claims jobs and watches their
        # render processes, which provide the isolation (jobs.execution.runner). GPU workers are
        # processes of their own, each pinned to its GPU (jobs/execution/gpus.py), so the
        # scheduler listens on loopback TCP for them. With the CPU worker alone there is
        # nothing to balance, so no work stealing (it rebalances every 100 ms).
        network = {"host": "127.0.0.1", "protocol": "tcp://", "scheduler_port": 0} if gpus else {}
        with dask.config.set({"distributed.scheduler.work-stealing": bool(gpus)}):
            # Dask's HTTP servers (dashboard, info pages, health, metrics) on loopback
            # only, not on every interface as by default; closed below unless asked for.
            self.cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                        dashboard_address="127.0.0.1:0",
                                        worker_dashboard_address="127.0.0.1:0",
                                        resources=CPU_WORKER, **network)
        self.client = Client(self.cluster)
        self.gpu_workers = start_gpu_workers(
            self.cluster.scheduler_address, gpus,
            {**os.environ, **dask_environment(QUIET_WORKER_CONFIG)}, dashboard=dashboard)
        if gpus:
            self.client.wait_for_workers(1 + gpus, timeout=120)
        if not dashboard:
            close_dashboards(self.client)

    @property
    def dashboard_url(self) -> str | None:
        """The embedded scheduler's dashboard, None when closed or not embedded."""
        if self.cluster is None or not self.dashboard:
            return None
        return f"http://127.0.0.1:{self.cluster.scheduler.http_server.port}/status"

    def unavailable(self, device_class: str) -> str | None:
        """Why this cluster cannot run jobs of ``device_class`` (None: it can, or with
        an external scheduler, it may once such workers join)."""
        if device_class == "gpu" and self.cluster is not None and not self.gpu_workers:
            return ("this service's embedded cluster has no GPU worker (no NVIDIA GPU "
                    "found): run GPU jobs on a service started with --scheduler and "
                    "`nirc-bench worker --gpus N` on the GPU machines")
        return None

    def submit(self, job: Job) -> None:
        """Run ``job`` on a worker (GPU jobs on a worker with the GPU resource); a sweep
        as its task graph of stage jobs, the sweep job last."""
        from distributed import fire_and_forget

        with self._lock:
            upstream = []
            try:
                stages = job_of(job).stages()
            except ValueError:  # its runner fails it, saying why
                stages = []
            if stages:
                rows = self.queue.stage_jobs(job, stages)
                futures: dict[str, Any] = {}
                for stage in stages:
                    futures[stage.name] = self._submit(rows[stage.name],
                                                       [futures[name] for name in stage.after])
                upstream = [futures[stage.name] for stage in final_stages(stages)]
            future = self._submit(job, upstream)
            fire_and_forget(future)
            self._tasks[job.id] = future

    def _submit(self, job: Job, upstream: list[Any]) -> Any:
        resources = GPU_WORKER if job.device_class == "gpu" else CPU_WORKER
        # A key of its own per dispatch: the client answers a known key with its old
        # (maybe failed) future instead of running the task again.
        self._dispatches += 1
        return self.client.submit(
            run_job_task, job.id, self.settings.model_dump(mode="json"), self.timeout_s,
            *upstream, key=f"nirc-job-{job.id}-{job.attempts}-{self._dispatches}",
            pure=False, resources=resources)

    def _on_its_way(self) -> list[int]:
        """Jobs whose task is still pending or running (finished tasks are forgotten)."""
        with self._lock:
            for job_id in [job_id for job_id, future in self._tasks.items() if future.done()]:
                del self._tasks[job_id]
            return list(self._tasks)

    def recover(self, jobs: list[Job] | None = None) -> list[int]:
        """Submit again the jobs that nothing runs (``jobs``, or every such job in the
        database: queued ones without a task, running ones whose lease expired).
        Returns their ids. A job named in ``jobs`` (submitted again) whose task is still
        on its way is looked at again when that task ends: a runner that meets a storage
        failure leaves its job queued for the next round (jobs.execution.runner), and the
        submission asked for it now."""
        busy = set(self._on_its_way())
        if jobs is None:
            jobs = self.queue.stranded(self.settings.job_lease_s, exclude=list(busy))
        else:
            for job in jobs:
                if job.id in busy and job.parent_id is None:
                    self._recover_when_done(job.id)
        lease_s = self.settings.job_lease_s
        stranded = [job for job in jobs if job.id not in busy
                    and job.parent_id is None and self.queue.is_stranded(job, lease_s)]
        for job in stranded:
            self.submit(job)
        return [job.id for job in stranded]

    def _recover_when_done(self, job_id: int) -> None:
        """When the task now running ``job_id`` ends, submit the job again if nothing
        runs it then (its runner deferred it)."""
        with self._lock:
            future = self._tasks.get(job_id)
        if future is None:
            return

        def again(_future: Any) -> None:
            try:
                job = self.queue.get(job_id)
                if job is not None:
                    self.recover([job])
            except Exception as err:  # noqa: BLE001 - logged; the timer's rounds retry
                if storage_failure(err) is None:
                    log.exception("dispatching job %s again failed", job_id)

        future.add_done_callback(again)

    def recover_every(self, interval_s: float) -> threading.Event:
        """Call :meth:`recover` every ``interval_s`` in a daemon thread, until the
        returned event is set. A storage failure (the database locked or full) only
        skips a round."""
        stop = threading.Event()

        def loop() -> None:
            while not stop.wait(interval_s):
                try:
                    recovered = self.recover()
                except Exception as err:  # noqa: BLE001 - logged; the next round retries
                    if storage_failure(err) is None:
                        log.exception("dispatching stranded jobs failed")
                    continue
                if recovered:
                    log.info("dispatched stranded jobs again: %s", recovered)

        threading.Thread(target=loop, name="nirc-bench-recover", daemon=True).start()
        return stop

    def close(self) -> None:
        self.queue.store.close()
        self.client.close()
        for process in self.gpu_workers:
            process.terminate()
            process.wait()
        if self.cluster is not None:
            self.cluster.close()
