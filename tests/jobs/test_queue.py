"""The durable job queue: dedupe, idempotency keys, exclusive claims, retries, recovery."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import pytest
from sqlalchemy import func, select, text
from sqlalchemy.exc import IntegrityError

from jobs.execution.queue import IdempotencyKeyReused, JobQueue
from jobs.record.models import Job

SPEC = {"scene": "cornell-box", "method": "pt"}


def test_identical_specs_and_idempotency_keys_return_the_existing_job(store):
    queue = JobQueue(store)
    first, created = queue.submit("render", SPEC, "key-a")
    again, created_again = queue.submit("render", SPEC, "key-a")
    assert created and not created_again and again.id == first.id
    keyed, created_keyed = queue.submit("render", SPEC, "key-b", idempotency_key="client-1")
    retried, created_retried = queue.submit("render", SPEC, "key-b", idempotency_key="client-1")
    assert created_keyed and not created_retried and retried.id == keyed.id
    # A failed job does not block a new submission of the same spec.
    queue.claim(first.id, "w")
    queue.fail(first.id, "bad", retry=False)
    fresh, created_fresh = queue.submit("render", SPEC, "key-a")
    assert created_fresh and fresh.id != first.id


def test_a_job_is_claimed_by_exactly_one_worker(store):
    queue = JobQueue(store)
    job, _ = queue.submit("render", SPEC, "k")
    with ThreadPoolExecutor(8) as pool:
        claims = list(pool.map(lambda i: queue.claim(job.id, f"w{i}"), range(8)))
    winners = [c for c in claims if c is not None]
    assert len(winners) == 1 and winners[0].attempts == 1
    assert queue.get(job.id).status == "running"


def test_failed_attempts_retry_until_max_attempts(store):
    queue = JobQueue(store)
    job, _ = queue.submit("render", SPEC, "k", max_attempts=2)
    queue.claim(job.id, "w")
    assert queue.fail(job.id, "crashed", retry=True) == "queued"
    assert queue.claim(job.id, "w").attempts == 2
    assert queue.fail(job.id, "crashed again", retry=True) == "failed"
    final = queue.get(job.id)
    assert final.status == "failed" and final.error == "crashed again"
    assert queue.claim(job.id, "w") is None


def test_cancel_and_progress(store):
    queue = JobQueue(store)
    queued, _ = queue.submit("render", SPEC, "q")
    assert queue.cancel(queued.id).status == "canceled"
    assert queue.claim(queued.id, "w") is None
    running, _ = queue.submit("render", SPEC, "r")
    queue.claim(running.id, "w")
    queue.set_progress(running.id, "seed 1/4", 3, 8)
    assert queue.get(running.id).progress == {"stage": "seed 1/4", "done": 3, "total": 8}
    assert queue.cancel(running.id).status == "running" and queue.cancel_requested(running.id)
    assert queue.fail(running.id, "canceled while running", retry=True) == "canceled"
    assert queue.cancel(999) is None


def ids(jobs) -> list[int]:
    return [job.id for job in jobs]


def test_stranded_jobs_and_lease_takeover(store):
    queue = JobQueue(store)
    a, _ = queue.submit("render", SPEC, "a")
    b, _ = queue.submit("render", SPEC, "b", max_attempts=1)
    c, _ = queue.submit("render", SPEC, "c")
    queue.claim(a.id, "dead worker")
    queue.claim(b.id, "dead worker")
    # Running jobs are stranded only once their lease has expired.
    assert ids(queue.stranded(lease_s=60)) == [c.id]
    assert ids(queue.stranded(lease_s=0)) == [a.id, b.id, c.id]
    assert ids(queue.stranded(lease_s=0, exclude=[c.id])) == [a.id, b.id]
    # A fresh heartbeat keeps the job with its runner; a stale one lets another take over.
    assert queue.claim(a.id, "new worker", lease_s=60) is None
    taken = queue.claim(a.id, "new worker", lease_s=0)
    assert taken.worker == "new worker" and taken.attempts == 2
    # No attempt left: a dead runner's job fails instead.
    assert queue.claim(b.id, "new worker", lease_s=0) is None
    assert not queue.expire(b.id, lease_s=60) and queue.expire(b.id, lease_s=0)
    assert queue.get(b.id).status == "failed" and "stopped" in queue.get(b.id).error


def test_a_sweeps_stages_are_made_once_and_go_with_their_sweep(store):
    from jobs.execution.graph import sweep_stages
    from jobs.protocol.spec import SweepSpec

    queue = JobQueue(store)
    spec = SweepSpec(scene="cornell-box", seeds=2, eps=[0.5], methods=["nrc"])
    sweep, _ = queue.submit("sweep", spec.model_dump(mode="json"), "sweep")
    stages = sweep_stages(spec)
    first = queue.stage_jobs(sweep, stages)
    again = queue.stage_jobs(sweep, stages)        # re-dispatched after a restart
    assert {n: j.id for n, j in first.items()} == {n: j.id for n, j in again.items()}
    assert [job.spec["name"] for job in queue.children(sweep.id)] == [s.name for s in stages]
    assert all(job.kind == "stage" and job.parent_id == sweep.id for job in first.values())
    assert ids(queue.stranded(lease_s=0)) == [sweep.id]   # stages go with their sweep
    # A stage fails for good: what needs it is abandoned with its error.
    reference, cache = first["reference"], first["nrc cache 1/2"]
    queue.claim(reference.id, "w")
    queue.fail(reference.id, "FileNotFoundError: no scene", retry=False)
    assert queue.abandon(cache.id, queue.upstream_error(cache)) == "failed"
    assert queue.get(cache.id).error == "stage 'reference' failed: FileNotFoundError: no scene"
    assert queue.abandon(sweep.id, queue.upstream_error(queue.get(sweep.id))) == "failed"
    # Canceling a sweep cancels its stages (queued at once, running ones asked to stop).
    other, _ = queue.submit("sweep", spec.model_dump(mode="json"), "other")
    stages_of_other = queue.stage_jobs(other, stages)
    running = stages_of_other["reference"]
    queue.claim(running.id, "w")
    queue.cancel(other.id)
    assert queue.get(other.id).status == "canceled"
    assert queue.cancel_requested(running.id) and queue.get(running.id).status == "running"
    assert {queue.get(j.id).status for n, j in stages_of_other.items() if n != "reference"} \
        == {"canceled"}


def test_a_sweeps_stage_work_is_summed(store):
    from jobs.execution.graph import sweep_stages
    from jobs.protocol.spec import SweepSpec

    queue = JobQueue(store)
    spec = SweepSpec(scene="cornell-box", seeds=2, eps=[0.5], methods=["nrc"])
    sweep, _ = queue.submit("sweep", spec.model_dump(mode="json"), "sweep")
    assert queue.stage_work(sweep.id) == {}
    stages = queue.stage_jobs(sweep, sweep_stages(spec))
    for name, work in (("reference", {"reference_rendered": 1, "snapshots_trained": 0}),
                       ("nrc cache 1/2", {"reference_rendered": 0, "snapshots_trained": 1}),
                       ("nrc cache 2/2", {"reference_rendered": 0, "snapshots_trained": 1})):
        queue.claim(stages[name].id, "w")
        assert queue.succeed(stages[name].id, work=work)
    assert queue.get(stages["reference"].id).work == {"reference_rendered": 1,
                                                      "snapshots_trained": 0}
    assert queue.stage_work(sweep.id) == {"reference_rendered": 1, "snapshots_trained": 2}


def test_concurrent_identical_submissions_make_exactly_one_job(store, monkeypatch):
    # Before 0007 the queue checked, then inserted: 50 threads made several jobs.
    queue = JobQueue(store)
    start = threading.Barrier(50)
    # The worst interleaving, every time: all 50 look before any of them inserts.
    looked = threading.Barrier(50)
    first_look = threading.local()
    existing = JobQueue._existing

    def look_then_wait(self, *args):
        found = existing(self, *args)
        if not getattr(first_look, "done", False):
            first_look.done = True
            looked.wait()
        return found

    monkeypatch.setattr(JobQueue, "_existing", look_then_wait)

    def submit(_: int) -> tuple[int, bool]:
        start.wait()
        job, created = queue.submit("render", SPEC, "same-spec")
        return job.id, created

    with ThreadPoolExecutor(50) as pool:
        answers = list(pool.map(submit, range(50)))
    assert len({job_id for job_id, _ in answers}) == 1
    assert sum(created for _, created in answers) == 1
    with store.session() as session:
        assert session.scalar(select(func.count()).select_from(Job)) == 1


def test_the_database_refuses_a_second_live_job_per_spec(store):
    queue = JobQueue(store)
    first, _ = queue.submit("render", SPEC, "k")
    with pytest.raises(IntegrityError), store.session(write=True) as session:
        session.add(Job(kind="render", spec=SPEC, spec_key="k", status="queued"))
    # A failed or canceled job does not count: the spec may run again.
    queue.cancel(first.id)
    with store.session(write=True) as session:
        session.add(Job(kind="render", spec=SPEC, spec_key="k", status="queued"))


def test_an_idempotency_key_reused_for_another_request_is_refused(store):
    queue = JobQueue(store)
    job, _ = queue.submit("render", SPEC, "k", idempotency_key="client-1")
    with pytest.raises(IdempotencyKeyReused, match="different request body"):
        queue.submit("render", {**SPEC, "seeds": 3}, "k3", idempotency_key="client-1")
    with pytest.raises(IdempotencyKeyReused, match="was used for a render"):
        queue.submit("sweep", SPEC, "k", idempotency_key="client-1")
    with pytest.raises(IdempotencyKeyReused):
        queue.submit("render", SPEC, "k", idempotency_key="client-1", device_class="gpu")
    again, created = queue.submit("render", SPEC, "k", idempotency_key="client-1")
    assert again.id == job.id and not created


def test_migration_0007_merges_duplicate_jobs_stored_before_it(store):
    from alembic import command

    from jobs.record.db import alembic_config, migrate

    config = alembic_config()
    with store.engine.begin() as conn:
        config.attributes["connection"] = conn
        command.downgrade(config, "0006")
    rows = [  # (spec_key, status, parent): two keys with duplicates, one without
        ("a", "queued", None), ("a", "succeeded", None), ("a", "running", None),
        ("a", "failed", None), ("b", "queued", None), ("b", "queued", None),
        ("c", "succeeded", None), ("b-stage", "queued", 6)]
    with store.engine.begin() as conn:
        for spec_key, status, parent in rows:
            conn.execute(text(
                "INSERT INTO jobs (kind, spec, spec_key, device_class, status, attempts, "
                "max_attempts, progress, cancel_requested, parent_id, created_at, updated_at) "
                "VALUES (:kind, '{}', :key, 'cpu', :status, 0, 3, '{}', false, :parent, "
                "CURRENT_TIMESTAMP, CURRENT_TIMESTAMP)"),
                {"kind": "stage" if parent else "sweep", "key": spec_key, "status": status,
                 "parent": parent})
    migrate(store.engine)
    queue = JobQueue(store)
    status = {job.id: (job.status, job.error) for job in queue.list(limit=100)}
    # Key a keeps its succeeded job (2), b its oldest (5); c is alone; failed stays failed.
    assert status[2][0] == "succeeded" and status[5][0] == "queued"
    assert status[7][0] == "succeeded" and status[4][0] == "failed"
    for merged, keeper in ((1, 2), (3, 2), (6, 5)):
        assert status[merged][0] == "canceled"
        assert f"merged into job {keeper}" in status[merged][1]
    assert status[8][0] == "canceled" and "merged into job 5" in status[8][1]
    # And from now on the database holds the line.
    assert queue.submit("render", SPEC, "a")[0].id == 2


def test_a_key_runs_at_most_its_limit_of_jobs_at_once(store):
    """One key's jobs beyond max_running_per_owner are not claimed (they stay queued,
    to be dispatched again): the key cannot hold every worker. Another key's job, and
    the same key's job once a slot is free, are claimed."""
    from jobs.execution.apikeys import create_api_key

    queue = JobQueue(store)
    (a, _), (b, _) = create_api_key(store, "a"), create_api_key(store, "b")
    first, second, theirs = (queue.submit("render", SPEC, key, owner_key_id=owner)[0]
                             for key, owner in (("1", a.id), ("2", a.id), ("3", b.id)))
    assert queue.claim(first.id, "w1", lease_s=60, max_running_per_owner=1) is not None
    assert queue.claim(second.id, "w2", lease_s=60, max_running_per_owner=1) is None
    assert queue.get(second.id).status == "queued"
    assert queue.claim(theirs.id, "w2", lease_s=60, max_running_per_owner=1) is not None
    queue.succeed(first.id, run_id=None)
    assert queue.claim(second.id, "w1", lease_s=60, max_running_per_owner=1) is not None
