"""The repository: references and runs written whole, read back detached."""

from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime

import pytest
from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError, InvalidRequestError

from jobs.record.models import Artifact, Reference, Run, RunStatus, SeedResult
from jobs.record.store import DuplicateKeyError, Store
from tests.jobs.factories import artifact_fields, reference_fields, run_fields, seed_fields


def count(store: Store, model: type) -> int:
    with store.session() as session:
        return session.scalar(select(func.count()).select_from(model)) or 0


def add_full_run(store: Store, **overrides: object) -> Run:
    reference = store.find_reference("ref-key-1") or store.add_reference(**reference_fields())
    return store.add_run(
        run_fields(reference_id=reference.id, **overrides),
        seed_results=[seed_fields(0), seed_fields(1)],
        artifacts=[
            artifact_fields("preview", "aa" * 32),
            artifact_fields("image", "bb" * 32, seed=0),
            artifact_fields("error_map", "cc" * 32, seed=1),
        ],
    )


def test_reference_round_trip(store: Store) -> None:
    added = store.add_reference(
        **reference_fields(), artifacts=[artifact_fields("variance", "dd" * 32)]
    )
    found = store.find_reference("ref-key-1")
    assert found is not None and found.id == added.id
    assert found.flip_exposures == [-3.5, 4.25]
    assert found.split_half == {"mrse": 1.5e-4, "flip": 0.01}
    assert found.settings["spp_per_pass"] == 64
    assert [a.kind for a in found.artifacts] == ["variance"]
    assert found.created_at.tzinfo is not None
    assert store.find_reference("missing") is None


def test_reference_key_is_unique(store: Store) -> None:
    first = store.add_reference(**reference_fields())
    with pytest.raises(DuplicateKeyError) as caught:
        store.add_reference(**reference_fields(spp=8192))
    assert caught.value.existing.id == first.id
    assert count(store, Reference) == 1
    # Enforced by the database itself, not only by the repository.
    with pytest.raises(IntegrityError), store.session(write=True) as session:
        session.add(Reference(**reference_fields()))


def test_delete_reference_keeps_runs(store: Store) -> None:
    run = add_full_run(store)
    reference_id = run.reference_id
    assert reference_id is not None
    store.add_reference(
        **reference_fields("ref-key-2"), artifacts=[artifact_fields("image", "ff" * 32)]
    )
    assert store.delete_reference(reference_id) is True
    assert store.delete_reference(reference_id) is False
    assert store.find_reference("ref-key-1") is None
    kept = store.get_run(run.id)
    assert kept is not None and kept.reference_id is None and kept.reference is None
    assert len(kept.seed_results) == 2
    # The same key can be stored again, as when a lost reference is re-rendered.
    assert store.add_reference(**reference_fields()).id != reference_id
    deleted = store.find_reference("ref-key-2")
    assert deleted is not None and store.delete_reference(deleted.id)
    assert count(store, Artifact) == 3  # the reference's artifact row went with it


def test_run_round_trip(store: Store) -> None:
    run = add_full_run(store, idempotency_key="job-1")
    # Everything get_run promises is usable after its session closed.
    got = store.get_run(run.id)
    assert got is not None
    assert got.status == RunStatus.SUCCEEDED
    assert got.metrics["mrse"]["ci"] == [0.09, 0.11]
    assert got.quality == {"finite": True, "nonfinite_pixels": 0}
    assert got.finished_at == datetime(2025, 1, 2, 3, 4, 5, tzinfo=UTC)
    assert got.created_at.tzinfo is not None
    assert got.reference is not None and got.reference.key == "ref-key-1"
    assert [s.seed for s in got.seed_results] == [0, 1]
    assert [a.kind for a in got.seed_results[0].artifacts] == ["image"]
    assert [a.kind for a in got.seed_results[1].artifacts] == ["error_map"]
    assert {a.kind for a in got.artifacts} == {"preview", "image", "error_map"}
    assert all(a.run_id == run.id for a in got.artifacts)
    assert run.seed_results[1].metrics == {"mrse": 1.1}  # add_run returns the same shape


def test_find_run_by_idempotency_key(store: Store) -> None:
    run = add_full_run(store, idempotency_key="job-1")
    found = store.find_run_by_idempotency_key("job-1")
    assert found is not None and found.id == run.id and len(found.seed_results) == 2
    assert store.find_run_by_idempotency_key("job-2") is None


def test_retried_job_does_not_duplicate(store: Store) -> None:
    first = add_full_run(store, idempotency_key="job-1")
    with pytest.raises(DuplicateKeyError) as caught:
        add_full_run(store, idempotency_key="job-1")
    assert caught.value.existing.id == first.id
    assert (count(store, Run), count(store, SeedResult), count(store, Artifact)) == (1, 2, 3)
    # Runs without a key never collide.
    add_full_run(store)
    add_full_run(store)
    assert count(store, Run) == 3


def test_a_run_is_never_half_written(store: Store) -> None:
    broken = artifact_fields("image", "ee" * 32, seed=1)
    broken["sha256"] = None  # NOT NULL: fails at the last insert
    with pytest.raises(IntegrityError):
        store.add_run(
            run_fields(idempotency_key="job-x"),
            seed_results=[seed_fields(0), seed_fields(1)],
            artifacts=[artifact_fields("preview", "aa" * 32), broken],
        )
    assert (count(store, Run), count(store, SeedResult), count(store, Artifact)) == (0, 0, 0)


def test_bad_input_is_explained(store: Store) -> None:
    with pytest.raises(ValueError, match="seed 7"):
        store.add_run(run_fields(), [seed_fields(0)], [artifact_fields("image", "aa" * 32, seed=7)])
    with pytest.raises(ValueError, match="twice"):
        store.add_run(run_fields(), [seed_fields(0), seed_fields(0)])
    with pytest.raises(IntegrityError):  # the status check constraint
        store.add_run(run_fields(status="running"))
    with pytest.raises(IntegrityError):  # foreign keys are enforced on SQLite
        store.add_run(run_fields(reference_id=12345))
    with pytest.raises(Exception, match="naive datetime"):
        store.add_run(run_fields(finished_at=datetime(2025, 1, 1)))
    assert count(store, Run) == 0


def test_artifact_needs_an_owner(store: Store) -> None:
    with pytest.raises(IntegrityError), store.session(write=True) as session:
        session.add(Artifact(**artifact_fields("image", "aa" * 32)))


def test_list_runs_filters(store: Store) -> None:
    a = add_full_run(store)
    b = add_full_run(store, method="nirc", device_key="cuda:rtx")
    c = add_full_run(store, scene_name="door", scene_fingerprint="fp-door", method="nirc")
    assert [r.id for r in store.list_runs()] == [c.id, b.id, a.id]  # newest first
    assert [r.id for r in store.list_runs(method="nirc")] == [c.id, b.id]
    assert [r.id for r in store.list_runs(scene="cornell-box")] == [b.id, a.id]
    assert [r.id for r in store.list_runs(scene="cornell-box", method="nirc")] == [b.id]
    assert [r.id for r in store.list_runs(device_key="cuda:rtx")] == [b.id]
    assert [r.id for r in store.list_runs(limit=1)] == [c.id]
    assert store.list_runs(scene="nowhere") == []


def test_unloaded_relationships_fail_loudly(store: Store) -> None:
    add_full_run(store)
    (listed,) = store.list_runs()
    assert listed.metrics["flip"] == 0.2  # columns are loaded
    with pytest.raises(InvalidRequestError, match="lazy='raise'"):
        _ = listed.seed_results


def test_concurrent_writers(store: Store) -> None:
    # Separate engines, as separate worker processes would have.
    from jobs.record.db import make_engine

    def write(worker: int) -> None:
        other = Store(make_engine(store.engine.url))
        try:
            for i in range(5):
                other.add_run(
                    run_fields(idempotency_key=f"w{worker}-{i}"),
                    [seed_fields(0)],
                    [artifact_fields("image", f"{worker:02d}" * 32, seed=0)],
                )
        finally:
            other.close()

    with ThreadPoolExecutor(max_workers=4) as pool:
        for future in [pool.submit(write, w) for w in range(4)]:
            future.result()
    assert count(store, Run) == 20
