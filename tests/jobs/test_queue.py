"""The durable job queue: dedupe, idempotency keys, exclusive claims, retries, recovery."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

from jobs.queue import JobQueue

SPEC = {"scene": "cornell-box", "method": "pt"}


def test_identical_specs_and_idempotency_keys_return_the_existing_job(store):
    queue = JobQueue(store)
    first, created = queue.submit("render", SPEC, "key-a")
    again, created_again = queue.submit("render", SPEC, "key-a")
    assert created and not created_again and again.id == first.id
    keyed, created_keyed = queue.submit("render", SPEC, "key-b", idempotency_key="client-1")
    retried, created_retried = queue.submit("render", {"other": 1}, "key-c",
                                            idempotency_key="client-1")
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


def test_unfinished_jobs_and_lease_takeover(store):
    queue = JobQueue(store)
    a, _ = queue.submit("render", SPEC, "a")
    b, _ = queue.submit("render", SPEC, "b", max_attempts=1)
    c, _ = queue.submit("render", SPEC, "c")
    queue.claim(a.id, "dead worker")
    queue.claim(b.id, "dead worker")
    assert queue.unfinished() == [a.id, b.id, c.id]
    # A fresh heartbeat keeps the job with its runner; a stale one lets another take over.
    assert queue.claim(a.id, "new worker", lease_s=60) is None
    taken = queue.claim(a.id, "new worker", lease_s=0)
    assert taken.worker == "new worker" and taken.attempts == 2
    # No attempt left: a dead runner's job fails instead.
    assert queue.claim(b.id, "new worker", lease_s=0) is None
    assert not queue.expire(b.id, lease_s=60) and queue.expire(b.id, lease_s=0)
    assert queue.get(b.id).status == "failed" and "stopped" in queue.get(b.id).error


def test_a_sweeps_stages_are_made_once_and_go_with_their_sweep(store):
    from jobs.graph import sweep_stages
    from jobs.spec import SweepSpec

    queue = JobQueue(store)
    spec = SweepSpec(scene="cornell-box", seeds=2, eps=[0.5], methods=["nrc"])
    sweep, _ = queue.submit("sweep", spec.model_dump(mode="json"), "sweep")
    stages = sweep_stages(spec)
    first = queue.stage_jobs(sweep, stages)
    again = queue.stage_jobs(sweep, stages)        # re-dispatched after a restart
    assert {n: j.id for n, j in first.items()} == {n: j.id for n, j in again.items()}
    assert [job.spec["name"] for job in queue.children(sweep.id)] == [s.name for s in stages]
    assert all(job.kind == "stage" and job.parent_id == sweep.id for job in first.values())
    assert queue.unfinished() == [sweep.id]        # stages are dispatched with their sweep
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
    from jobs.graph import sweep_stages
    from jobs.spec import SweepSpec

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
