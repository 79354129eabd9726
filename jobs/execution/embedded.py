"""The CLI's own render (``nirc-bench render`` without ``--server``), run as the
service runs its jobs: a job row in the local database, run by the runner
(jobs/execution/runner.py) in a render process of its own, through the one executor.

A native crash of the render (heap corruption, a segfault in Dr.Jit, an LLVM abort)
then kills the render process, not the user's command: the job ends ``failed`` with
the signal and the stage it was in, stored like any failure of the service's jobs,
and :class:`RenderFailed` says so. The job

* is tried once and has no timeout (it is the user's own command, watched by them);
* never stands for another job with the same spec (its spec key is its own): whether
  a run stored earlier is the result is the executor's ``reuse`` (same spec, scene,
  reference, commit, versions and device), as when the CLI rendered in process;
* renders on the device the CLI's own process would have chosen
  (``NIRC_BENCH_VARIANT``, else a usable GPU, else the CPU);
* is canceled on Ctrl-C. A command killed outright (SIGKILL) leaves it running
  with a lease that expires: a service started on the same data folder then runs it
  like any stranded job.

Progress comes from the render process as it reports it (the status pipe), so the
CLI's bars and lines are the executor's own.
"""

from __future__ import annotations

import math
import os
import socket
import uuid
from collections.abc import Callable
from pathlib import Path

from jobs.execution.queue import JobQueue
from jobs.execution.queued import QueuedRender
from jobs.execution.runner import (
    DEFERRED,
    EXIT_JOB_FAILED,
    VARIANT_OF_DEVICE_CLASS,
    Follow,
    run_job,
)
from jobs.protocol.executor import RunSummary
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import RenderSpec
from jobs.record.config import Settings
from jobs.record.models import JobStatus
from jobs.record.store import Store
from jobs.views.export import export_run
from renderers.backend import SUPPORTED_VARIANTS, BackendError, default_variant


class RenderFailed(Exception):
    """The render job did not succeed; the message names why and the stored job.
    ``user_error``: its input was at fault (an unknown scene, a method that does not
    apply to it), not the render."""

    def __init__(self, message: str, *, user_error: bool) -> None:
        super().__init__(message)
        self.user_error = user_error


def device_class() -> str:
    """The device class of the variant this process would render with."""
    variant = default_variant()
    for name, of_class in VARIANT_OF_DEVICE_CLASS.items():
        if of_class == variant:
            return name
    raise BackendError(f"unsupported variant '{variant}'; choose one of "
                       f"{', '.join(SUPPORTED_VARIANTS)}")


def render_here(job: RenderJob, store: Store, settings: Settings,
                progress: Callable[[str, int, int], None] | None = None, *,
                reuse: bool = False, out_dir: Path | None = None) -> RunSummary:
    """Run ``job`` in a render process of its own and return what ``execute`` returns
    for it (exported to ``out_dir`` if given); raises :class:`RenderFailed`."""
    queue = JobQueue(store)
    devices = device_class()
    queued = QueuedRender(job=job)
    row, _ = queue.submit(queued.kind, queued.stored(),
                          f"{queued.key(devices)}:embedded:{uuid.uuid4().hex}",
                          device_class=devices, max_attempts=1)
    attempts: list[tuple[int, str]] = []
    status = run_job(row.id, settings, worker=f"cli-{os.getpid()}@{socket.gethostname()}",
                     timeout_s=math.inf,
                     follow=Follow(progress=progress, reuse=reuse,
                                   attempt=lambda code, reason: attempts.append((code, reason))))
    if status == DEFERRED:      # back in the queue (a storage failure): nothing would run it
        status = queue.abandon(row.id, queue.get(row.id).error or "not run")
    done = queue.get(row.id)
    if status != JobStatus.SUCCEEDED.value:
        if [code for code, _ in attempts] == [EXIT_JOB_FAILED]:
            raise RenderFailed(attempts[0][1], user_error=True)  # the error's own message
        raise RenderFailed(f"render failed: {done.error}; the job is stored as {status} "
                           f"(job {row.id})", user_error=False)
    run = store.get_run(done.run_id)
    work = done.work or {}
    summary = RunSummary.of_stored(run, RenderSpec.model_validate(run.params["spec"]), settings,
                                   reference_rendered_now=bool(work.get("reference_rendered")),
                                   reused=bool(work.get("run_reused")))
    if out_dir is not None:
        summary.files = export_run(run, summary.to_json(), settings, out_dir)
    return summary
