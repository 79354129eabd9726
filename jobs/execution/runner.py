"""Run a queued job in an isolated child process, with retries, timeout and cancel.

A render can take the process down with it (a Dr.Jit/LLVM abort, a leak), so
jobs never run in the worker itself but in a child process — a new interpreter
(``python -m jobs.execution.runner --serve FD``; spawned, not forked: nothing of the
parent's JIT state is inherited) that reads job ids on stdin and answers each
with a status line on a pipe of its own, file descriptor FD. Its stdout and
stderr go to its log file: Mitsuba's log, warnings included, and anything a
library prints land there and can never be read as a status. Starting Python + Mitsuba + the JIT costs seconds, so a healthy
child serves further jobs (at most ``MAX_JOBS_PER_CHILD``, then it is
replaced, so a slow leak cannot grow without bound); any failure retires it.
The parent — a Dask task in the service, or a test — claims the job, hands it
to the child and watches:

* status 0: the child stored the result and marked the job succeeded;
* status 3: the job's input is wrong (unknown scene, bad parameters) or its
  device class cannot render here (a GPU job on a worker without a usable
  GPU): the child marked it failed with the message; retrying would fail the
  same way;
* the child dies (an abort, a signal, an out-of-memory kill), or the attempt
  times out or is canceled (the parent kills the child): the attempt failed;
  the job goes back to the queue until ``max_attempts``.

The child stores the run under the idempotency key ``job-<id>``, so an
attempt that died after storing its result does not store it twice: the next
attempt finds it and only marks the job done. Children are killed with their
parent (Linux ``PR_SET_PDEATHSIG``), so a killed worker leaves no render behind.
A child renders with the variant of its jobs' device class (``cpu``: LLVM,
``gpu``: CUDA, on the GPU its worker was given — jobs/execution/gpus.py), so a CPU job on a
GPU worker still renders on the CPU it asked for.
"""

from __future__ import annotations

import os
import re
import select
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Sequence
from typing import Any

from jobs.execution.queue import JobQueue
from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.record.models import JobStatus
from renderers.backend import BackendError

#: Status of a job that failed for good (bad input).
EXIT_JOB_FAILED = 3
#: Seconds between progress writes to the database.
PROGRESS_INTERVAL_S = 1.0
#: Jobs a child serves before it is replaced by a fresh one.
MAX_JOBS_PER_CHILD = 100
#: The Mitsuba variant a job's device class renders with (renderers/backend.py).
VARIANT_OF_DEVICE_CLASS = {"cpu": "llvm_ad_rgb", "gpu": "cuda_ad_rgb"}
#: Set by Dask's nanny for its worker processes (1 thread, aggressive malloc trimming);
#: a render process uses every core and the allocator's defaults.
_DASK_WORKER_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                            "MALLOC_TRIM_THRESHOLD_")
#: Mitsuba colours its log lines even in a file; a failure reason is plain text.
_ANSI_COLOR = re.compile(r"\x1b\[[0-9;]*m")


def run_job(job_id: int, settings: Settings, *, worker: str, timeout_s: float | None = None,
            poll_s: float = 1.0, upstream: Sequence[str] = ()) -> str:
    """Claim and run ``job_id`` until it succeeds, fails for good or is canceled.

    ``upstream``: the final statuses of the stages this job needs (a sweep's task
    graph); if one did not succeed, the job is abandoned without running.
    Returns the job's final status (or its current one if another worker has it).
    """
    store = open_store(settings)
    queue = JobQueue(store)
    lease_s = settings.job_lease_s
    try:
        if any(status != JobStatus.SUCCEEDED.value for status in upstream):
            job = queue.get(job_id)
            # Stopped by a cancel upstream (and nothing failed): canceled, not failed.
            canceled = JobStatus.CANCELED.value in upstream and not any(
                status not in (JobStatus.SUCCEEDED.value, JobStatus.CANCELED.value)
                for status in upstream)
            return (queue.abandon(job_id, queue.upstream_error(job), canceled=canceled)
                    if job else "missing")
        while True:
            claimed = queue.claim(job_id, worker, lease_s=lease_s)
            if claimed is None:
                job = queue.get(job_id)
                if job is None or job.status != JobStatus.RUNNING.value:
                    return job.status if job else "missing"
                # Another runner has it: wait until it finishes or its lease expires.
                if queue.expire(job_id, lease_s):
                    continue
                time.sleep(poll_s)
                continue
            child = _child_for(settings, claimed.device_class)
            status, reason = child.run(job_id, queue, _timeout_of(claimed, settings, timeout_s),
                                       poll_s)
            if status in (0, EXIT_JOB_FAILED):
                return queue.get(job_id).status
            if queue.fail(job_id, reason, retry=True) != JobStatus.QUEUED.value:
                return queue.get(job_id).status
    finally:
        store.close()


def _timeout_of(job: Any, settings: Settings, timeout_s: float | None) -> float:
    """The service's ``--job-timeout``, else one from the job's work estimate
    (jobs.execution.work.default_timeout_s): no attempt runs unbounded."""
    if timeout_s is not None:
        return timeout_s
    from jobs.execution.work import default_timeout_s, job_work

    try:
        return default_timeout_s(job_work(job.kind, job.spec), settings)
    except (ValueError, KeyError, TypeError):  # a spec the child will refuse at once
        return settings.job_timeout_min_s


class _Child:
    """One render process serving jobs over a line protocol (see the module doc)."""

    def __init__(self, settings: Settings, device_class: str) -> None:
        self.settings = settings
        self.device_class = device_class
        self.jobs = 0
        env = {key: value for key, value in os.environ.items()
               if key not in _DASK_WORKER_VARIABLES}
        env.update(NIRC_BENCH_DATA_DIR=str(settings.data_dir),
                   NIRC_BENCH_DATABASE_URL=str(settings.database_url),
                   NIRC_BENCH_VARIANT=VARIANT_OF_DEVICE_CLASS[device_class])
        # The log is a file, not a pipe: a chatty child must never block on it.
        self.log = tempfile.TemporaryFile("w+")
        status_read, status_write = os.pipe()
        self.status = os.fdopen(status_read, "r")
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "jobs.execution.runner", "--serve", str(status_write)], env=env,
                text=True, stdin=subprocess.PIPE, stdout=self.log, stderr=self.log,
                pass_fds=(status_write,), preexec_fn=die_with_parent)
        finally:
            os.close(status_write)     # the child's copy only: EOF when it dies

    def usable(self, settings: Settings, device_class: str) -> bool:
        return (self.proc.poll() is None and self.jobs < MAX_JOBS_PER_CHILD
                and (settings.data_dir, settings.database_url, device_class)
                == (self.settings.data_dir, self.settings.database_url, self.device_class))

    def run(self, job_id: int, queue: JobQueue, timeout_s: float | None,
            poll_s: float) -> tuple[int, str]:
        """Run one attempt; returns (status, reason if the attempt failed)."""
        self.jobs += 1
        try:
            self.proc.stdin.write(f"{job_id}\n")
            self.proc.stdin.flush()
        except BrokenPipeError:
            return -1, self.close("the render process was gone before the job started")
        started = time.monotonic()
        while True:
            ready, _, _ = select.select([self.status], [], [], poll_s)
            if ready:
                line = self.status.readline()
                if line:
                    status = int(line)
                    if status != 0:
                        self.close()
                    return status, ""
                return -1, self.close()          # EOF: the child died mid-job
            queue.heartbeat(job_id)
            if timeout_s is not None and time.monotonic() - started > timeout_s:
                return -1, self.close(f"timed out after {timeout_s:g} s (attempt killed)")
            if queue.cancel_requested(job_id):
                return -1, self.close("canceled while running")

    def close(self, reason: str | None = None) -> str:
        """Retire the child (killing it if needed); returns why the attempt failed."""
        if self.proc.poll() is None:
            self.proc.kill()
        exitcode = self.proc.wait()
        tail: list[str] = []
        if not self.log.closed:
            self.log.seek(0)
            tail = _ANSI_COLOR.sub("", self.log.read()).strip().splitlines()
            self.log.close()
            self.status.close()
        if reason is not None:
            return reason
        if exitcode < 0:
            name = (signal.Signals(-exitcode).name
                    if -exitcode in signal.Signals._value2member_map_ else str(-exitcode))
            what = f"the render process was killed by {name}"
        else:
            what = f"the render process exited with status {exitcode}"
        return f"{what}: {tail[-1]}" if tail else what


_children = threading.local()


def _child_for(settings: Settings, device_class: str) -> _Child:
    """This thread's render process, replaced when it is dead, used up, elsewhere or
    on the other device class."""
    child: _Child | None = getattr(_children, "child", None)
    if child is None or not child.usable(settings, device_class):
        if child is not None:
            child.close()
        child = _children.child = _Child(settings, device_class)
    return child


def die_with_parent() -> None:
    """In the child, before exec: be killed when the runner dies (Linux
    PR_SET_PDEATHSIG), so a killed worker or service leaves no render behind."""
    if sys.platform.startswith("linux"):
        import ctypes

        PR_SET_PDEATHSIG = 1
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


# ---------------------------------------------------------------------------
# The child process
# ---------------------------------------------------------------------------

def execute_job(job: Any, store: Any, settings: Settings, progress: Any) -> dict[str, Any]:
    """Run a job's spec through the one executor; returns what ``JobQueue.succeed``
    records: the result ids, or a stage's work counters."""
    from jobs.protocol.executor import execute
    from jobs.protocol.spec import RenderSpec, SweepSpec
    from jobs.protocol.sweep import run_stage, run_sweep

    if job.kind == "stage":
        work = run_stage(SweepSpec(**job.spec["sweep"]), job.spec["task"], store, settings,
                         progress=progress)
        return {"work": work}
    if job.kind == "sweep":
        result = run_sweep(SweepSpec(**job.spec), store, settings, progress=progress,
                           stage_work=JobQueue(store).stage_work(job.id))
        return {"sweep_id": result.sweep_id}
    key = f"job-{job.id}"
    stored = store.find_run_by_idempotency_key(key)
    if stored is not None:  # an earlier attempt stored it, then died
        return {"run_id": stored.id}
    summary = execute(RenderSpec(**job.spec), store, settings, progress=progress,
                      idempotency_key=key)
    return {"run_id": summary.run_id}


def _throttled(queue: JobQueue, job_id: int):
    last = [0.0]

    def report(stage: str, done: int, total: int) -> None:
        now = time.monotonic()
        if now - last[0] >= PROGRESS_INTERVAL_S or done == total:
            last[0] = now
            queue.set_progress(job_id, stage, done, total)

    return report


def run_one(job_id: int, store: Any, settings: Settings) -> int:
    """Run a claimed job, store the result, mark it; returns its status code."""
    queue = JobQueue(store)
    job = queue.get(job_id)
    if job is None or job.status != JobStatus.RUNNING.value:
        return EXIT_JOB_FAILED
    try:
        result = execute_job(job, store, settings, _throttled(queue, job_id))
    # Bad input, or a device class this worker cannot render: the same on every attempt.
    except (ValueError, FileNotFoundError, BackendError) as err:
        queue.fail(job_id, f"{type(err).__name__}: {err}", retry=False)
        return EXIT_JOB_FAILED
    queue.succeed(job_id, **result)
    return 0


def serve(status_fd: int) -> int:
    """Child entry point: run the job ids read from stdin, one status line each on
    ``status_fd`` (nothing else writes there; stdout is the log).

    An unexpected exception ends the process (its state may be damaged): the
    parent sees the pipe close and fails the attempt with the last log line.
    """
    settings = Settings()
    store = open_store(settings)
    with os.fdopen(status_fd, "w") as status_out:
        for line in sys.stdin:
            try:
                status = run_one(int(line), store, settings)
            except Exception:  # noqa: BLE001 - reported through the log, then exit
                traceback.print_exc()
                return 1
            status_out.write(f"{status}\n")
            status_out.flush()
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] != "--serve" or not sys.argv[2].isdigit():
        sys.exit("usage: python -m jobs.execution.runner --serve STATUS_FD  (started by the job runner)")
    sys.exit(serve(int(sys.argv[2])))
