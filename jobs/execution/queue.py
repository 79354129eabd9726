"""The durable job queue: every job is a database row before anything runs it.

State machine (``jobs.record.models.JobStatus``)::

    queued --claim--> running --succeed--> succeeded
       ^                 |  \\--fail (user error, or attempts used up)--> failed
       |                 |   \\--cancel--> canceled
       +--- retry -------+   (the attempt crashed, was killed or timed out)

Every transition is one conditional UPDATE (``WHERE status = ...``), so two
workers cannot both claim a job, and a duplicated task finds the job taken or
finished. A running job's runner renews a heartbeat (``updated_at``) while it
watches its child; when the heartbeat is older than the lease, the runner is
presumed dead (its worker or the whole service was killed) and another runner
may take the job over (one more attempt). On start the service dispatches
every job that is not final again (:meth:`JobQueue.unfinished`): queued ones
start, running ones are taken over once their lease expires — or simply
reported done if their runner is alive and finishes.

A sweep's stages (jobs/execution/graph.py) are jobs too, children of the sweep's job:
they are made once per sweep job (:meth:`JobQueue.stage_jobs`, idempotent),
canceled with it, and re-dispatched through it, never on their own. A job
whose upstream stage failed is *abandoned*: failed without running, with the
stage's error.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import and_, or_, select, update
from sqlalchemy.exc import IntegrityError

from jobs.protocol.spec import RenderSpec, SweepSpec
from jobs.record.models import DEDUPE_JOB_STATES, FINAL_JOB_STATES, Job, JobStatus
from jobs.record.store import Store
from renderers.seeding import digest

#: Live states: a new identical submission returns the existing job instead.
_DEDUPE_STATES = [state.value for state in DEDUPE_JOB_STATES]


def spec_key(kind: str, spec: RenderSpec | SweepSpec, device_class: str) -> str:
    """The dedupe key of a submitted render or sweep: its spec, the worker class and
    today's estimator and metric versions (after a version bump nothing old matches)."""
    return digest(kind, spec.model_dump(mode="json"), device_class, spec.versions())


def _now() -> datetime:
    return datetime.now(UTC)


#: Inserts tried before giving up on a key that keeps conflicting (each conflict means
#: another submission won; a retry reads its job, or inserts if that one has failed).
_INSERT_ATTEMPTS = 5


class IdempotencyKeyReused(ValueError):
    """An Idempotency-Key already used for a different request (kind, spec or worker
    class): answering with the other request's job would be a silent mistake."""


def _same_request(job: Job, kind: str, spec: dict[str, Any], device_class: str,
                  idempotency_key: str | None) -> Job:
    """``job``, found for a submission; refuses it if found by an Idempotency-Key that
    an earlier, different request used."""
    if idempotency_key is None or job.idempotency_key != idempotency_key:
        return job
    if job.kind != kind:
        raise IdempotencyKeyReused(
            f"Idempotency-Key {idempotency_key!r} was used for a {job.kind} (job {job.id}); "
            f"use a new key for this {kind}")
    if job.spec != spec or job.device_class != device_class:
        raise IdempotencyKeyReused(
            f"Idempotency-Key {idempotency_key!r} was used for job {job.id} with a different "
            "request body or worker class; use a new key for a different request")
    return job


def _new_job(kind: str, spec: dict[str, Any], spec_key: str, idempotency_key: str | None,
             device_class: str, max_attempts: int, parent_id: int | None) -> Job:
    return Job(kind=kind, spec=spec, spec_key=spec_key, idempotency_key=idempotency_key,
               device_class=device_class, status=JobStatus.QUEUED.value, attempts=0,
               max_attempts=max_attempts, progress={}, cancel_requested=False,
               parent_id=parent_id)


class JobQueue:
    """Job rows and their transitions, over a :class:`~jobs.record.store.Store`."""

    def __init__(self, store: Store) -> None:
        self.store = store

    # ---- submission and reads ----

    def submit(self, kind: str, spec: dict[str, Any], spec_key: str, *,
               idempotency_key: str | None = None, device_class: str = "cpu",
               max_attempts: int = 3, parent_id: int | None = None) -> tuple[Job, bool]:
        """Store a new queued job, or return the existing one: the job submitted
        under ``idempotency_key``, else a live or succeeded job with the same spec.
        Returns (job, created).

        Exactly once: the database holds at most one queued, running or succeeded
        job per ``spec_key`` (the partial unique index ``uq_jobs_live_spec_key``)
        and one job per ``idempotency_key``, so of concurrent identical submissions
        one insert wins and the others catch its IntegrityError and return the
        winner. Raises :class:`IdempotencyKeyReused` when ``idempotency_key`` names
        a job of another kind, spec or device class.
        """
        for _ in range(_INSERT_ATTEMPTS):
            existing = self._existing(spec_key, idempotency_key)
            if existing is not None:
                return _same_request(existing, kind, spec, device_class, idempotency_key), False
            job = _new_job(kind, spec, spec_key, idempotency_key, device_class,
                           max_attempts, parent_id)
            try:
                with self.store.session(write=True) as session:
                    session.add(job)
            except IntegrityError:
                # Another submission inserted the same spec or key first: return it
                # (read again; if it has since failed, insert anew).
                continue
            return job, True
        raise RuntimeError(f"job submission for spec {spec_key[:12]} kept conflicting")

    def _existing(self, spec_key: str, idempotency_key: str | None) -> Job | None:
        with self.store.session() as session:
            if idempotency_key is not None:
                job = session.scalars(
                    select(Job).where(Job.idempotency_key == idempotency_key)).one_or_none()
                if job is not None:
                    return job
            return session.scalars(
                select(Job).where(Job.spec_key == spec_key, Job.status.in_(_DEDUPE_STATES))
                .order_by(Job.id.desc()).limit(1)).one_or_none()

    def stage_jobs(self, parent: Job, stages: Sequence[Any]) -> dict[str, Job]:
        """The stage jobs of the sweep job ``parent`` (jobs.execution.graph.Stage), made on first
        call and returned by name afterwards (their keys derive from the parent's id).

        All missing stages are inserted in one transaction (a sweep's stages cost one
        write, not one per stage); a concurrent call that inserted them first makes
        this one read theirs."""
        def key(stage: Any) -> str:
            return f"job-{parent.id}-stage-{stage.name}"

        for _ in range(_INSERT_ATTEMPTS):
            made = {job.idempotency_key: job for job in self.children(parent.id)}
            missing = [stage for stage in stages if key(stage) not in made]
            if not missing:
                return {stage.name: made[key(stage)] for stage in stages}
            try:
                with self.store.session(write=True) as session:
                    session.add_all(_new_job(
                        "stage", {"sweep": parent.spec, "name": stage.name, "task": stage.task},
                        key(stage), key(stage), parent.device_class, parent.max_attempts,
                        parent.id) for stage in missing)
            except IntegrityError:
                continue
        raise RuntimeError(f"the stage jobs of job {parent.id} kept conflicting")

    def children(self, parent_id: int) -> list[Job]:
        """The stage jobs of a sweep job, in the order they were made."""
        with self.store.session() as session:
            return list(session.scalars(
                select(Job).where(Job.parent_id == parent_id).order_by(Job.id)))

    def stage_work(self, parent_id: int) -> dict[str, int]:
        """The work counters of a sweep job's stages, summed ({} without stages)."""
        total: dict[str, int] = {}
        for stage in self.children(parent_id):
            for name, count in (stage.work or {}).items():
                total[name] = total.get(name, 0) + count
        return total

    def get(self, job_id: int) -> Job | None:
        with self.store.session() as session:
            return session.get(Job, job_id)

    def list(self, status: str | None = None, *, limit: int = 100) -> list[Job]:
        """Newest first."""
        query = select(Job).order_by(Job.id.desc()).limit(limit)
        if status is not None:
            query = query.where(Job.status == status)
        with self.store.session() as session:
            return list(session.scalars(query))

    # ---- transitions ----

    def _transition(self, job_id: int, where: Sequence[Any], **values: Any) -> bool:
        with self.store.session(write=True) as session:
            result = session.execute(
                update(Job).where(Job.id == job_id, *where)
                .values(updated_at=_now(), **values))
            return result.rowcount == 1

    def claim(self, job_id: int, worker: str, lease_s: float | None = None) -> Job | None:
        """queued -> running for ``worker`` (one more attempt), or take over a running
        job whose heartbeat is older than ``lease_s``; None if not claimable."""
        claimable = Job.status == JobStatus.QUEUED.value
        if lease_s is not None:
            stale = _now() - timedelta(seconds=lease_s)
            claimable = or_(claimable, and_(Job.status == JobStatus.RUNNING.value,
                                            Job.updated_at < stale))
        claimed = self._transition(
            job_id, [claimable, Job.attempts < Job.max_attempts, Job.cancel_requested.is_(False)],
            status=JobStatus.RUNNING.value, attempts=Job.attempts + 1, worker=worker,
            started_at=_now(), error=None)
        return self.get(job_id) if claimed else None

    def heartbeat(self, job_id: int) -> None:
        """The runner of a running job is alive (renews its lease)."""
        self._transition(job_id, [Job.status == JobStatus.RUNNING.value])

    def expire(self, job_id: int, lease_s: float) -> bool:
        """A running job whose runner died on its last attempt: failed."""
        stale = _now() - timedelta(seconds=lease_s)
        return self._transition(
            job_id, [Job.status == JobStatus.RUNNING.value, Job.updated_at < stale,
                     or_(Job.attempts >= Job.max_attempts, Job.cancel_requested.is_(True))],
            status=JobStatus.FAILED.value, finished_at=_now(),
            error="the runner of the last attempt stopped (worker or service killed)")

    def set_progress(self, job_id: int, stage: str, done: int, total: int) -> None:
        self._transition(job_id, [Job.status == JobStatus.RUNNING.value],
                         progress={"stage": stage, "done": done, "total": total})

    def succeed(self, job_id: int, *, run_id: int | None = None,
                sweep_id: int | None = None, work: dict[str, int] | None = None) -> bool:
        return self._transition(job_id, [Job.status == JobStatus.RUNNING.value],
                                status=JobStatus.SUCCEEDED.value, run_id=run_id,
                                sweep_id=sweep_id, work=work, finished_at=_now())

    def fail(self, job_id: int, error: str, *, retry: bool) -> str:
        """End a running attempt with ``error``: back to queued when ``retry`` and
        attempts remain, else failed. Returns the new status."""
        job = self.get(job_id)
        if job is None or job.status != JobStatus.RUNNING.value:
            return job.status if job else JobStatus.FAILED.value
        if retry and job.attempts < job.max_attempts and not job.cancel_requested:
            self._transition(job_id, [Job.status == JobStatus.RUNNING.value],
                             status=JobStatus.QUEUED.value, error=error, worker=None)
            return JobStatus.QUEUED.value
        final = JobStatus.CANCELED if job.cancel_requested else JobStatus.FAILED
        self._transition(job_id, [Job.status == JobStatus.RUNNING.value],
                         status=final.value, error=error, finished_at=_now())
        return final.value

    def abandon(self, job_id: int, error: str, *, canceled: bool = False) -> str:
        """A queued job whose upstream stage did not succeed: failed without running, or
        canceled if its cancel was asked for or the upstream stage was ``canceled``.
        Returns its status."""
        failed = JobStatus.CANCELED if canceled else JobStatus.FAILED
        for final, requested in ((JobStatus.CANCELED, True), (failed, False)):
            self._transition(job_id, [Job.status == JobStatus.QUEUED.value,
                                      Job.cancel_requested.is_(requested)],
                             status=final.value, error=error, finished_at=_now())
        job = self.get(job_id)
        return job.status if job else JobStatus.FAILED.value

    def upstream_error(self, job: Job) -> str:
        """Why ``job``'s upstream stages did not all succeed: the first stage of its
        sweep (its own stages, or its siblings) that failed or was canceled."""
        family = self.children(job.parent_id if job.parent_id is not None else job.id)
        for stage in family:
            if stage.status in (JobStatus.FAILED.value, JobStatus.CANCELED.value):
                return f"stage '{stage.spec.get('name')}' {stage.status}: {stage.error}"
        return "an upstream stage did not succeed"

    def cancel(self, job_id: int) -> Job | None:
        """Cancel a queued job now; ask a running one to stop (its runner kills it).
        Canceling a sweep cancels its stages."""
        job = self.get(job_id)
        if job is None or job.status in [s.value for s in FINAL_JOB_STATES]:
            return job
        for stage in self.children(job_id):
            self.cancel(stage.id)
        self._transition(job_id, [Job.status == JobStatus.QUEUED.value],
                         status=JobStatus.CANCELED.value, cancel_requested=True,
                         finished_at=_now())
        self._transition(job_id, [Job.status == JobStatus.RUNNING.value],
                         cancel_requested=True)
        return self.get(job_id)

    def cancel_requested(self, job_id: int) -> bool:
        job = self.get(job_id)
        return bool(job and job.cancel_requested)

    def unfinished(self) -> list[int]:
        """Ids of jobs that are queued or running, oldest first (dispatched again on
        start; a sweep's stages go with their sweep)."""
        with self.store.session() as session:
            return list(session.scalars(
                select(Job.id).where(Job.status.in_([JobStatus.QUEUED.value,
                                                     JobStatus.RUNNING.value]),
                                     Job.parent_id.is_(None))
                .order_by(Job.id)))
