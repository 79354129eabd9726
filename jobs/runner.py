"""Run a queued job in an isolated child process, with retries, timeout and cancel.

A render can take the process down with it (a Dr.Jit/LLVM abort, a leak), so
each attempt runs in a fresh child process — a new interpreter started with
``python -m jobs.runner JOB_ID`` (spawned, not forked: nothing of the parent's
JIT state is inherited). The parent — a Dask task in the service, or the
test — only claims the job, starts the child, and watches it:

* exit 0: the child stored the result and marked the job succeeded;
* exit 3: the job's input is wrong (unknown scene, bad parameters): the child
  marked it failed with the message; retrying would fail the same way;
* anything else (an abort, a signal, a timeout, an out-of-memory kill): the
  attempt failed; the job goes back to the queue until ``max_attempts``.

The child stores the run under the idempotency key ``job-<id>``, so an
attempt that died after storing its result does not store it twice: the next
attempt finds it and only marks the job done.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from typing import Any

from jobs.config import Settings
from jobs.db import open_store
from jobs.models import JobStatus
from jobs.queue import JobQueue

#: Exit status of a child whose job failed for good (bad input).
EXIT_JOB_FAILED = 3
#: Seconds between progress writes to the database.
PROGRESS_INTERVAL_S = 0.5


def run_job(job_id: int, settings: Settings, *, worker: str, timeout_s: float | None = None,
            poll_s: float = 0.5) -> str:
    """Claim and run ``job_id`` until it succeeds, fails for good or is canceled.

    Returns the job's final status (or its current one if another worker has it).
    """
    store = open_store(settings)
    queue = JobQueue(store)
    lease_s = settings.job_lease_s
    try:
        while True:
            if queue.claim(job_id, worker, lease_s=lease_s) is None:
                job = queue.get(job_id)
                if job is None or job.status != JobStatus.RUNNING.value:
                    return job.status if job else "missing"
                # Another runner has it: wait until it finishes or its lease expires.
                if queue.expire(job_id, lease_s):
                    continue
                time.sleep(poll_s)
                continue
            exitcode, reason = _attempt(job_id, settings, queue, timeout_s, poll_s)
            if exitcode in (0, EXIT_JOB_FAILED):
                return queue.get(job_id).status
            if queue.fail(job_id, reason, retry=True) != JobStatus.QUEUED.value:
                return queue.get(job_id).status
    finally:
        store.close()


def _attempt(job_id: int, settings: Settings, queue: JobQueue, timeout_s: float | None,
             poll_s: float) -> tuple[int, str]:
    """Run one attempt in a child; returns (exit status, reason if it failed)."""
    env = {**os.environ, "NIRC_BENCH_DATA_DIR": str(settings.data_dir),
           "NIRC_BENCH_DATABASE_URL": str(settings.database_url)}
    # stderr goes to a file, not a pipe: a chatty child must never block on a full pipe.
    with tempfile.TemporaryFile("w+") as stderr:
        child = subprocess.Popen([sys.executable, "-m", "jobs.runner", str(job_id)], env=env,
                                 stdout=subprocess.DEVNULL, stderr=stderr,
                                 preexec_fn=_die_with_parent)
        started = time.monotonic()
        while True:
            try:
                exitcode = child.wait(timeout=poll_s)
                break
            except subprocess.TimeoutExpired:
                queue.heartbeat(job_id)
                if timeout_s is not None and time.monotonic() - started > timeout_s:
                    _kill(child)
                    return -1, f"timed out after {timeout_s:g} s (attempt killed)"
                if queue.cancel_requested(job_id):
                    _kill(child)
                    return -1, "canceled while running"
        if exitcode in (0, EXIT_JOB_FAILED):
            return exitcode, ""
        stderr.seek(0)
        return exitcode, _describe_exit(exitcode, stderr.read().strip())


def _die_with_parent() -> None:
    """In the child, before exec: be killed when the runner dies (Linux
    PR_SET_PDEATHSIG), so a killed worker or service leaves no render behind."""
    if sys.platform.startswith("linux"):
        import ctypes

        PR_SET_PDEATHSIG = 1
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def _kill(child: subprocess.Popen) -> None:
    child.kill()
    child.wait()


def _describe_exit(exitcode: int, stderr: str) -> str:
    if exitcode < 0:
        name = signal.Signals(-exitcode).name if -exitcode in signal.Signals._value2member_map_ \
            else str(-exitcode)
        what = f"the render process was killed by {name}"
    else:
        what = f"the render process exited with status {exitcode}"
    tail = stderr.splitlines()[-1] if stderr else ""
    return f"{what}{': ' + tail if tail else ''}"


# ---------------------------------------------------------------------------
# The child process
# ---------------------------------------------------------------------------

def execute_job(job: Any, store: Any, settings: Settings, progress: Any) -> dict[str, int]:
    """Run a job's spec through the one executor; returns the result ids."""
    from jobs.executor import execute
    from jobs.spec import RenderSpec, SweepSpec
    from jobs.sweep import run_sweep

    if job.kind == "sweep":
        result = run_sweep(SweepSpec(**job.spec), store, settings, progress=progress)
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


def main(job_id: int) -> int:
    """Child entry point: run the job, store the result, mark it; see the module doc."""
    settings = Settings()
    store = open_store(settings)
    queue = JobQueue(store)
    job = queue.get(job_id)
    if job is None or job.status != JobStatus.RUNNING.value:
        return EXIT_JOB_FAILED
    try:
        result = execute_job(job, store, settings, _throttled(queue, job_id))
    except (ValueError, FileNotFoundError) as err:  # bad input: the same on every attempt
        queue.fail(job_id, f"{type(err).__name__}: {err}", retry=False)
        return EXIT_JOB_FAILED
    queue.succeed(job_id, **result)
    return 0


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1])))
