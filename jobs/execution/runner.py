"""Run a queued job in an isolated child process, with retries, timeout and cancel.

A render can take the process down with it (a Dr.Jit/LLVM abort, a leak), so
jobs never run in the worker itself but in a child process — a new interpreter
(``python -m jobs.execution.runner --serve FD``; spawned, not forked: nothing of the
parent's JIT state is inherited) that reads job ids on stdin (``ID``, or ``ID reuse``:
a run of the same spec stored earlier may be the result, ``execute``'s ``reuse``) and
answers each with a status line on a pipe of its own, file descriptor FD, after
progress lines (``progress DONE TOTAL STAGE``, at most every
``PIPE_PROGRESS_INTERVAL_S`` but for a new or finished stage), which tell the parent
the stage a dying child was in. Its stdout and
stderr go to its log file: Mitsuba's log, warnings included, and anything a
library prints land there and can never be read as a status. Starting Python + Mitsuba + the JIT costs seconds, so a healthy
child serves further jobs (at most ``MAX_JOBS_PER_CHILD``, then it is
replaced, so a slow leak cannot grow without bound); any failure retires it.
The parent — a Dask task in the service, the CLI's own render
(jobs/execution/embedded.py), or a test — claims the job, hands it to the child and
watches:

* status 0: the child stored the result and marked the job succeeded;
* status 3: the job's input is wrong (unknown scene, bad parameters) or its
  device class cannot render here (a GPU job on a worker without a usable
  GPU): the child marked it failed with the message (the line carries it too, for
  a caller that shows it); retrying would fail the same way;
* status 4: the child could not write the data folder or the database (disk
  full, a file size limit, the database locked past its timeout); the line
  carries the cause. The job goes back to the queue without using up an attempt
  (the job is not at fault) *and this runner leaves it*: retrying at once would
  meet the same full disk, so the service's next round of dispatching
  (jobs/execution/dispatch.py) runs it again; the child stays (it is healthy);
* the child dies (an abort, a signal, an out-of-memory kill), or the attempt
  times out or is canceled (the parent kills the child): the attempt failed;
  the job goes back to the queue until ``max_attempts``. A child that exits on
  its own is given time to finish exiting, so its real exit status is reported
  (never "killed by SIGKILL" for a process that was already ending), with the
  stage it last reported ("killed by SIGABRT during stage 'seed 2/4' (3/16)").

The runner itself survives its database failing under it. A heartbeat that
cannot be written is retried while the lease lasts; once a whole lease has passed
without one, the runner kills the child and gives the job up as a status 4: back to
the queue, using up no attempt (the requeue is retried while the database stays
unwritable, up to ``STORAGE_RETRY_LEASES`` leases: a job left running would be taken
over with one more attempt). A claim or a transition that fails for storage reasons
leaves the job queued, or running with a lease that will expire: ``run_job``
then returns ``"deferred"`` and the service dispatches the job again later. A job
whose upstream stage was deferred is deferred too, never abandoned.

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
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TextIO

from jobs.execution.queue import JobQueue
from jobs.record.config import Settings
from jobs.record.db import migrate, open_store
from jobs.record.models import JobStatus
from jobs.record.storage import describe, storage_failure
from jobs.record.store import Store
from renderers.backend import BackendError

#: Status of a job that failed for good (bad input).
EXIT_JOB_FAILED = 3
#: Status of an attempt that could not write the data folder or the database.
EXIT_STORAGE = 4
#: What :func:`run_job` returns for a job left to be dispatched again later (its claim
#: or a transition met a storage failure, its owner's running limit was reached, or an
#: upstream stage was deferred); not a job status.
DEFERRED = "deferred"
#: Leases a runner keeps trying to put back a job it gave up for a storage failure.
STORAGE_RETRY_LEASES = 10
#: Seconds a child that closed its status pipe is given to finish exiting.
EXIT_GRACE_S = 5.0
#: Seconds between progress writes to the database.
PROGRESS_INTERVAL_S = 1.0
#: Seconds between progress lines on the status pipe within one stage.
PIPE_PROGRESS_INTERVAL_S = 0.1
#: The first word of a progress line on the status pipe.
PROGRESS_LINE = "progress"
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


@dataclass(frozen=True)
class Follow:
    """What a caller that waits on its job itself (the CLI's own render) gets besides
    the final status, and asks of the render."""

    #: Each progress report of the render, as the render process makes it.
    progress: Callable[[str, int, int], None] | None = None
    #: Each attempt's end: the render process's status, or -1 when it died or was
    #: stopped, and why the attempt failed.
    attempt: Callable[[int, str], None] | None = None
    #: A run of the same spec stored earlier may be the result (``execute``'s reuse).
    reuse: bool = False


def run_job(job_id: int, settings: Settings, *, worker: str, timeout_s: float | None = None,
            poll_s: float = 1.0, upstream: Sequence[str] = (),
            follow: Follow = Follow()) -> str:
    """Claim and run ``job_id`` until it succeeds, fails for good or is canceled.

    ``upstream``: the final statuses of the stages this job needs (a sweep's task
    graph); if one did not succeed, the job is abandoned without running.
    Returns the job's final status (or its current one if another worker has it),
    or :data:`DEFERRED` when it is left to be dispatched again. An interrupt
    (Ctrl-C) kills the render process and cancels the job before it is raised on.
    """
    queue = JobQueue(_store_for(settings))
    try:
        return _run(queue, job_id, settings, worker, timeout_s, poll_s, upstream, follow)
    except Exception as err:
        if storage_failure(err) is None:
            raise
        # Queued, or running with a lease that will expire: dispatched again later.
        return DEFERRED


_stores = threading.local()


def _store_for(settings: Settings) -> Store:
    """This thread's store of ``settings``' database, migrated (or refused, if a newer
    nirc-bench migrated it) as ``open_store`` does on every call.

    Its engine, and so its pooled connections, serve every job the thread runs: an
    engine per job connected anew each time (~40 ms a job on PostgreSQL, measured).
    Replaced when the thread runs jobs of another database, and in a forked process,
    whose copy of the pool holds the parent's connections: it lets them go without
    closing them (closing would end the parent's sessions)."""
    key = (os.getpid(), str(settings.database_url), settings.db_lock_timeout_s)
    cached: tuple[tuple[int, str, float | None], Store] | None = getattr(_stores, "entry", None)
    if cached is not None:
        cached_key, store = cached
        if cached_key == key:
            migrate(store.engine)
            return store
        if cached_key[0] == key[0]:
            store.close()
        else:
            store.engine.dispose(close=False)
    _stores.entry = None
    store = open_store(settings)
    _stores.entry = (key, store)
    return store


def _run(queue: JobQueue, job_id: int, settings: Settings, worker: str,
         timeout_s: float | None, poll_s: float, upstream: Sequence[str],
         follow: Follow) -> str:
    lease_s = settings.job_lease_s
    if DEFERRED in upstream:
        return DEFERRED
    if any(status != JobStatus.SUCCEEDED.value for status in upstream):
        job = queue.get(job_id)
        # Stopped by a cancel upstream (and nothing failed): canceled, not failed.
        canceled = JobStatus.CANCELED.value in upstream and not any(
            status not in (JobStatus.SUCCEEDED.value, JobStatus.CANCELED.value)
            for status in upstream)
        return (queue.abandon(job_id, queue.upstream_error(job), canceled=canceled)
                if job else "missing")
    while True:
        claimed = queue.claim(job_id, worker, lease_s=lease_s,
                              max_running_per_owner=settings.max_running_jobs_per_key)
        if claimed is None:
            job = queue.get(job_id)
            if job is None:
                return "missing"
            if job.status == JobStatus.QUEUED.value:
                return DEFERRED     # its owner runs as many jobs as it may: later
            if job.status != JobStatus.RUNNING.value:
                return job.status
            # Another runner has it: wait until it finishes or its lease expires.
            if queue.expire(job_id, lease_s):
                continue
            time.sleep(poll_s)
            continue
        child = _child_for(settings, claimed.device_class)
        try:
            status, reason = child.run(job_id, queue,
                                       _timeout_of(claimed, settings, timeout_s, queue.store),
                                       poll_s, lease_s, follow)
        except KeyboardInterrupt:
            queue.cancel(job_id)
            queue.fail(job_id, child.close("interrupted (Ctrl-C) while running"), retry=False)
            raise
        if follow.attempt:
            follow.attempt(status, reason)
        if status in (0, EXIT_JOB_FAILED):
            return queue.get(job_id).status
        if status == EXIT_STORAGE:
            return _requeue_uncounted(queue, job_id, reason, poll_s, lease_s)
        if queue.fail(job_id, reason, retry=True) != JobStatus.QUEUED.value:
            return queue.get(job_id).status


def _requeue_uncounted(queue: JobQueue, job_id: int, reason: str, poll_s: float,
                       lease_s: float) -> str:
    """An attempt stopped by a storage failure back to the queue, using up no attempt
    (:data:`DEFERRED`), or the job's status if it is no longer this runner's; tried
    again every ``poll_s`` while the database cannot be written, for
    :data:`STORAGE_RETRY_LEASES` leases (then the storage error is raised)."""
    deadline = time.monotonic() + STORAGE_RETRY_LEASES * lease_s
    while True:
        try:
            status = queue.fail(job_id, reason, retry=True, count=False)
        except Exception as err:
            if storage_failure(err) is None or time.monotonic() > deadline:
                raise
            time.sleep(poll_s)
            continue
        return DEFERRED if status == JobStatus.QUEUED.value else status


def _timeout_of(job: Any, settings: Settings, timeout_s: float | None, store: Any) -> float:
    """The service's ``--job-timeout``, else one from the job's size: its samples at
    the slowest expected rate (jobs.execution.work.default_timeout_s), and at least
    twice its estimated time on this device (jobs.execution.timecost): no attempt runs
    unbounded, and none is killed for being as long as its estimate."""
    if timeout_s is not None:
        return timeout_s
    from jobs.execution.queued import job_of
    from jobs.execution.timecost import TIMEOUT_OVER_ESTIMATE
    from jobs.execution.work import default_timeout_s

    try:
        queued = job_of(job)
    except ValueError:  # a spec the child will refuse at once
        return settings.job_timeout_min_s
    work = queued.attempt_work()
    estimate = queued.time(work, store, job.device_class)
    return max(default_timeout_s(work, settings),
               settings.job_timeout_min_s + TIMEOUT_OVER_ESTIMATE * estimate.seconds)


class _Child:
    """One render process serving jobs over a line protocol (see the module doc)."""

    #: The stage the current job last reported: (stage, done, total).
    stage: tuple[str, int, int] | None = None
    #: What was read of the status pipe after its last complete line.
    pending: bytes = b""

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
        # Unbuffered: a line read ahead into a buffer would be invisible to select().
        self.status = os.fdopen(status_read, "rb", buffering=0)
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

    def run(self, job_id: int, queue: JobQueue, timeout_s: float | None, poll_s: float,
            lease_s: float, follow: Follow = Follow()) -> tuple[int, str]:
        """Run one attempt; returns (status, reason if the attempt failed): the child's
        status, :data:`EXIT_STORAGE` when the heartbeat could not be written for a
        whole lease (the child killed), or -1 when it died or was stopped. The lease is renewed, and the
        timeout and a cancel looked for, every ``poll_s`` however often the child
        reports progress."""
        self.jobs += 1
        self.stage = None
        try:
            self.proc.stdin.write(f"{job_id}{' reuse' if follow.reuse else ''}\n")
            self.proc.stdin.flush()
        except BrokenPipeError:
            return -1, self.close("the render process was gone before the job started")
        started = last_beat = next_check = time.monotonic()
        while True:
            ready, _, _ = select.select([self.status], [], [],
                                        max(0.0, next_check - time.monotonic()))
            if ready:
                chunk = self.status.read(1 << 16)
                if not chunk:                    # EOF: the child died mid-job
                    return -1, self.close(ended=True)
                self.pending += chunk
                while b"\n" in self.pending:
                    line, _, self.pending = self.pending.partition(b"\n")
                    answer = self._answer(line.decode(errors="replace"), follow)
                    if answer is not None:
                        return answer
            if time.monotonic() < next_check:
                continue
            next_check = time.monotonic() + poll_s
            try:
                queue.heartbeat(job_id)
                canceled = queue.cancel_requested(job_id)
                last_beat = time.monotonic()
            except Exception as err:
                if storage_failure(err) is None:
                    raise
                # The lease is lost once a whole one passes without a heartbeat:
                # another runner may take the job over, so this one must stop.
                if time.monotonic() - last_beat > lease_s:
                    return EXIT_STORAGE, self.close(f"the runner gave the job up: no heartbeat for "
                                          f"{lease_s:g} s, the job's lease ({describe(err)})")
                continue
            if timeout_s is not None and time.monotonic() - started > timeout_s:
                return -1, self.close(f"timed out after {timeout_s:g} s (attempt killed)")
            if canceled:
                return -1, self.close("canceled while running")

    def _answer(self, line: str, follow: Follow) -> tuple[int, str] | None:
        """A progress line noted (and passed to ``follow.progress``), or the job's
        status line as (status, reason)."""
        word, _, rest = line.strip().partition(" ")
        if word == PROGRESS_LINE:
            done, total, stage = rest.split(" ", 2)
            self.stage = stage, int(done), int(total)
            if follow.progress:
                follow.progress(*self.stage)
            return None
        # A storage failure leaves the child healthy: it serves the next job.
        if int(word) not in (0, EXIT_STORAGE):
            self.close()
        return int(word), rest

    def close(self, reason: str | None = None, *, ended: bool = False) -> str:
        """Retire the child (killing it if needed); returns why the attempt failed.

        ``ended``: the child closed its status pipe, so it is exiting on its own; it
        gets :data:`EXIT_GRACE_S` to finish before it is killed, so that its own exit
        status is what the reason names."""
        if ended:
            try:
                self.proc.wait(timeout=EXIT_GRACE_S)
            except subprocess.TimeoutExpired:
                pass
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
        if self.stage is not None:
            stage, done, total = self.stage
            what += f" during stage '{stage}' ({done}/{total})"
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

def _reporter(queue: JobQueue, job_id: int, pipe: TextIO | None):
    """report(stage, done, total): to the job's row at most every PROGRESS_INTERVAL_S
    (and when a stage finishes), and as a progress line on ``pipe`` at most every
    PIPE_PROGRESS_INTERVAL_S (and when a stage starts or finishes)."""
    stored, sent = [0.0], [0.0, ""]

    def report(stage: str, done: int, total: int) -> None:
        now = time.monotonic()
        if pipe is not None and (stage != sent[1] or done == total
                                 or now - sent[0] >= PIPE_PROGRESS_INTERVAL_S):
            sent[:] = now, stage
            pipe.write(f"{PROGRESS_LINE} {done} {total} {' '.join(stage.split())}\n")
            pipe.flush()
        if now - stored[0] >= PROGRESS_INTERVAL_S or done == total:
            stored[0] = now
            try:
                queue.set_progress(job_id, stage, done, total)
            except Exception as err:
                # Progress is for the eyes only: a render goes on without it (its
                # result is written, or refused, at the end).
                if storage_failure(err) is None:
                    raise

    return report


def run_one(job_id: int, store: Any, settings: Settings, pipe: TextIO | None = None,
            reuse: bool = False) -> str:
    """Run a claimed job, store the result, mark it; returns its status line: the code,
    and for bad input the message (one line). Progress goes to the job's row and, as
    progress lines, to ``pipe`` (the status pipe)."""
    from jobs.execution.queued import job_of

    queue = JobQueue(store)
    job = queue.get(job_id)
    if job is None or job.status != JobStatus.RUNNING.value:
        return str(EXIT_JOB_FAILED)
    try:
        result = job_of(job).run(store, settings, _reporter(queue, job_id, pipe),
                                 job_id=job_id, reuse=reuse)
    # Bad input, or a device class this worker cannot render: the same on every attempt.
    except (ValueError, FileNotFoundError, BackendError) as err:
        queue.fail(job_id, f"{type(err).__name__}: {err}", retry=False)
        return f"{EXIT_JOB_FAILED} {' '.join(str(err).split())}"
    queue.succeed(job_id, **result)
    return "0"


def serve(status_fd: int) -> int:
    """Child entry point: run the job ids read from stdin, one status line each on
    ``status_fd``, after the job's progress lines (nothing else writes there; stdout is
    the log).

    A storage failure (a full disk, a file size limit, the database locked) is
    answered ``4 <cause>`` on the status pipe: the log may be on the full disk
    itself, the pipe is not. Any other unexpected exception ends the process (its
    state may be damaged): the parent sees the pipe close and fails the attempt with
    the last log line.
    """
    settings = Settings()
    store = open_store(settings)
    with os.fdopen(status_fd, "w") as status_out:
        for line in sys.stdin:
            job_id, *flags = line.split()
            try:
                answer = run_one(int(job_id), store, settings, status_out,
                                 reuse="reuse" in flags)
            except Exception as err:  # noqa: BLE001 - reported, then exit
                if storage_failure(err) is not None:
                    answer = f"{EXIT_STORAGE} {describe(err)}"
                else:
                    traceback.print_exc()
                    return 1
            status_out.write(f"{answer}\n")
            status_out.flush()
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] != "--serve" or not sys.argv[2].isdigit():
        sys.exit("usage: python -m jobs.execution.runner --serve STATUS_FD  (started by the job runner)")
    sys.exit(serve(int(sys.argv[2])))
