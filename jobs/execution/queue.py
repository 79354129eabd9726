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
presumed dead (its worker or the whole service was killed, or it could not write
the database) and another runner may take the job over (one more attempt). The
service dispatches again, at start and then on a timer, every job that nothing is
running (:meth:`JobQueue.stranded`): queued ones whose task ended without running
them (the claim failed: database locked, disk full) and running ones whose lease
expired (jobs/execution/dispatch.py).

Jobs belong to the API key that submitted them (``owner_key_id``); a key's
Idempotency-Keys are its own, and a key may hold at most a given number of
unfinished jobs (:class:`TooManyJobs` beyond) and run at most a given number at once
(a claim beyond waits: the job stays queued and is dispatched again later).

A sweep's stages (jobs/execution/graph.py) are jobs too, children of the sweep's job:
they are made once per sweep job (:meth:`JobQueue.stage_jobs`, idempotent),
canceled with it, and re-dispatched through it, never on their own. A job
whose upstream stage failed is *abandoned*: failed without running, with the
stage's error.

A transition that the database refuses for a storage reason (full, locked) is
remembered by the process (:data:`STORAGE_FAULT`) until one succeeds: a running job
whose lease expired meanwhile is *stalled* (:meth:`JobQueue.stalled`), which the API
serves with the reason instead of a ``running`` with stale progress; its row cannot
say so, the database being what failed.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import and_, func, or_, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, aliased

from jobs.protocol.spec import keyed_budget
from jobs.record.models import DEDUPE_JOB_STATES, FINAL_JOB_STATES, ApiKey, Job, JobStatus
from jobs.record.storage import describe, storage_failure
from jobs.record.store import Store
from renderers.seeding import digest

#: Live states: a new identical submission returns the existing job instead.
_DEDUPE_STATES = [state.value for state in DEDUPE_JOB_STATES]


def spec_key(kind: str, spec: Any, device_class: str) -> str:
    """The dedupe key of a submitted render, sweep or reproduction: its spec, the worker
    class and the versions it depends on (``spec.versions()``: today's estimator and
    metric versions, a reproduction's commit; after a bump nothing old matches)."""
    return digest(kind, keyed_budget(spec.model_dump(mode="json")), device_class,
                  spec.versions())


def _now() -> datetime:
    return datetime.now(UTC)


#: Inserts tried before giving up on a key that keeps conflicting (each conflict means
#: another submission won; a retry reads its job, or inserts if that one has failed).
_INSERT_ATTEMPTS = 5


class StorageFault:
    """The last storage failure of a job transition in this process (None once a
    transition succeeds again): what a stalled job is waiting for."""

    reason: str | None = None

    @contextmanager
    def watch(self) -> Iterator[None]:
        try:
            yield
        except Exception as err:
            if storage_failure(err) is not None:
                self.reason = describe(err)
            raise
        self.reason = None


#: The process's one record (the embedded cluster's runners share the service's).
STORAGE_FAULT = StorageFault()


class IdempotencyKeyReused(ValueError):
    """An Idempotency-Key already used for a different request (kind, spec or worker
    class): answering with the other request's job would be a silent mistake."""


class TooManyJobs(RuntimeError):
    """The submitting key already holds as many unfinished jobs as it may."""


def scoped_idempotency_key(owner_key_id: int | None, key: str | None) -> str | None:
    """The stored form of a client's Idempotency-Key: prefixed by the submitting API
    key, so that two keys never share one (nor meet the queue's own stage keys)."""
    if key is None or owner_key_id is None:
        return key
    return f"apikey-{owner_key_id}:{key}"


def _lock_owner(session: Session, owner_key_id: int) -> None:
    """Serialize the counting writes of one owner: PostgreSQL locks the key's row (on
    SQLite every write transaction already holds the database's write lock)."""
    if session.get_bind().dialect.name == "postgresql":
        session.execute(select(ApiKey.id).where(ApiKey.id == owner_key_id).with_for_update())


def _same_request(job: Job, kind: str, spec: dict[str, Any], device_class: str,
                  idempotency_key: str | None, stored_key: str | None) -> Job:
    """``job``, found for a submission; refuses it if found by an Idempotency-Key that
    an earlier, different request used (``stored_key``: its scoped form)."""
    if stored_key is None or job.idempotency_key != stored_key:
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
             device_class: str, max_attempts: int, parent_id: int | None,
             owner_key_id: int | None) -> Job:
    return Job(kind=kind, spec=spec, spec_key=spec_key, idempotency_key=idempotency_key,
               device_class=device_class, status=JobStatus.QUEUED.value, attempts=0,
               max_attempts=max_attempts, progress={}, cancel_requested=False,
               parent_id=parent_id, owner_key_id=owner_key_id)


class JobQueue:
    """Job rows and their transitions, over a :class:`~jobs.record.store.Store`."""

    def __init__(self, store: Store) -> None:
        self.store = store

    # ---- submission and reads ----

    def submit(self, kind: str, spec: dict[str, Any], spec_key: str, *,
               idempotency_key: str | None = None, device_class: str = "cpu",
               max_attempts: int = 3, parent_id: int | None = None,
               owner_key_id: int | None = None,
               max_unfinished: int | None = None,
               admit: Callable[[], None] | None = None) -> tuple[Job, bool]:
        """Store a new queued job, or return the existing one: the job submitted
        under ``idempotency_key`` (by the same ``owner_key_id``), else a live or
        succeeded job with the same spec (whoever submitted it: the work is done
        once). Returns (job, created).

        Exactly once: the database holds at most one queued, running or succeeded
        job per ``spec_key`` (the partial unique index ``uq_jobs_live_spec_key``)
        and one job per stored idempotency key, so of concurrent identical
        submissions one insert wins and the others catch its IntegrityError and
        return the winner. Raises :class:`IdempotencyKeyReused` when
        ``idempotency_key`` names a job of another kind, spec or device class, and
        :class:`TooManyJobs` when the owner already holds ``max_unfinished`` queued
        or running jobs (counted in the inserting transaction). ``admit`` is called
        before a new job is inserted, never when an existing job answers (it costs
        nothing new); what it raises refuses the submission.
        """
        stored_key = scoped_idempotency_key(owner_key_id, idempotency_key)
        for _ in range(_INSERT_ATTEMPTS):
            existing = self._existing(spec_key, stored_key)
            if existing is not None:
                return _same_request(existing, kind, spec, device_class, idempotency_key,
                                     stored_key), False
            if admit is not None:
                admit()
            job = _new_job(kind, spec, spec_key, stored_key, device_class,
                           max_attempts, parent_id, owner_key_id)
            try:
                with self.store.session(write=True) as session:
                    if owner_key_id is not None and max_unfinished is not None:
                        self._check_unfinished(session, owner_key_id, max_unfinished)
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

    @staticmethod
    def _check_unfinished(session: Session, owner_key_id: int, limit: int) -> None:
        _lock_owner(session, owner_key_id)
        held = session.scalar(select(func.count()).select_from(Job).where(
            Job.owner_key_id == owner_key_id, Job.parent_id.is_(None),
            Job.status.in_([JobStatus.QUEUED.value, JobStatus.RUNNING.value])))
        if held >= limit:
            raise TooManyJobs(f"this API key already has {held} unfinished jobs, the most "
                              f"this service allows per key (max_jobs_per_key = {limit}); "
                              "submit again when one has finished, or cancel one")

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
                        parent.id, parent.owner_key_id) for stage in missing)
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
        with STORAGE_FAULT.watch(), self.store.session(write=True) as session:
            result = session.execute(
                update(Job).where(Job.id == job_id, *where)
                .values(updated_at=_now(), **values))
            return result.rowcount == 1

    def claim(self, job_id: int, worker: str, lease_s: float | None = None,
              max_running_per_owner: int | None = None) -> Job | None:
        """queued -> running for ``worker`` (one more attempt), or take over a running
        job whose heartbeat is older than ``lease_s``; None if not claimable — also
        while the job's owner already runs ``max_running_per_owner`` other jobs whose
        lease holds (the job stays queued, to be dispatched again later)."""
        claimable = Job.status == JobStatus.QUEUED.value
        stale = _now() - timedelta(seconds=lease_s) if lease_s is not None else None
        if stale is not None:
            claimable = or_(claimable, and_(Job.status == JobStatus.RUNNING.value,
                                            Job.updated_at < stale))
        conditions = [claimable, Job.attempts < Job.max_attempts,
                      Job.cancel_requested.is_(False)]
        with STORAGE_FAULT.watch(), self.store.session(write=True) as session:
            owner = session.scalar(select(Job.owner_key_id).where(Job.id == job_id))
            if owner is not None and max_running_per_owner is not None:
                _lock_owner(session, owner)
                other = aliased(Job)
                running = select(func.count()).select_from(other).where(
                    other.owner_key_id == owner, other.id != job_id,
                    other.status == JobStatus.RUNNING.value,
                    *([other.updated_at >= stale] if stale is not None else []))
                conditions.append(running.scalar_subquery() < max_running_per_owner)
            claimed = session.execute(
                update(Job).where(Job.id == job_id, *conditions).values(
                    updated_at=_now(), status=JobStatus.RUNNING.value,
                    attempts=Job.attempts + 1, worker=worker, started_at=_now(), error=None)
            ).rowcount == 1
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

    def fail(self, job_id: int, error: str, *, retry: bool, count: bool = True) -> str:
        """End a running attempt with ``error``: back to queued when ``retry`` and
        attempts remain, else failed. Returns the new status. ``count=False``: the
        attempt does not use one up (it met a full disk, not a fault of the job)."""
        job = self.get(job_id)
        if job is None or job.status != JobStatus.RUNNING.value:
            return job.status if job else JobStatus.FAILED.value
        if not count:
            retry = True
        if retry and (job.attempts < job.max_attempts or not count) \
                and not job.cancel_requested:
            self._transition(job_id, [Job.status == JobStatus.RUNNING.value],
                             status=JobStatus.QUEUED.value, error=error, worker=None,
                             **({} if count else {"attempts": Job.attempts - 1}))
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

    @staticmethod
    def stalled(job: Job, lease_s: float) -> str | None:
        """Why a running job whose lease expired is not running: ``'storage: <cause>'``
        while this process cannot write the database; None otherwise (a job that runs,
        or one whose runner died, which the next dispatch takes over)."""
        reason = STORAGE_FAULT.reason
        if reason is None or job.status != JobStatus.RUNNING.value:
            return None
        return f"storage: {reason}" if JobQueue.is_stranded(job, lease_s) else None

    @staticmethod
    def is_stranded(job: Job, lease_s: float) -> bool:
        """Whether nothing can be running ``job`` as read: queued, or running with an
        expired lease (see :meth:`stranded`)."""
        if job.status == JobStatus.QUEUED.value:
            return True
        return (job.status == JobStatus.RUNNING.value
                and job.updated_at < _now() - timedelta(seconds=lease_s))

    def stranded(self, lease_s: float, exclude: Sequence[int] = ()) -> list[Job]:
        """Jobs that nothing is running, oldest first: queued ones, and running ones
        whose heartbeat is older than ``lease_s``; a sweep's stages go with their
        sweep, and ``exclude`` lists jobs the caller knows to be on their way."""
        stale = _now() - timedelta(seconds=lease_s)
        with self.store.session() as session:
            return list(session.scalars(
                select(Job).where(
                    or_(Job.status == JobStatus.QUEUED.value,
                        and_(Job.status == JobStatus.RUNNING.value, Job.updated_at < stale)),
                    Job.parent_id.is_(None), Job.id.not_in(list(exclude)))
                .order_by(Job.id)))
