"""Results know what computed them: versions are stored, are part of every dedupe key
(so a result of an older version is never reused), and old rows migrate to version 1."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

from alembic import command

from jobs.execution.queue import JobQueue, spec_key
from jobs.protocol.references import reference_key
from jobs.protocol.spec import RenderSpec, SweepSpec
from jobs.record.db import alembic_config, migrate
from jobs.record.store import Store
from jobs.sweeps.snapshots import snapshot_key
from renderers import methods
from renderers.methods.nrc import NRCParams
from renderers.reference import ReferenceSettings
from tests.jobs.factories import reference_fields, run_fields

SPEC = RenderSpec(scene="cornell-box", resolution=8, seeds=2)
SWEEP = SweepSpec(scene="cornell-box", eps=[0.5], resolution=8)
PREPARED = SimpleNamespace(scene=SimpleNamespace(fingerprint="fp", resolution=(8, 8)),
                           reference=SimpleNamespace(key="ref"))


def _keys() -> list[str]:
    return [SPEC.key(), SWEEP.key("cpu"), spec_key("render", SPEC, "cpu"),
            spec_key("sweep", SWEEP, "cpu"),
            snapshot_key(PREPARED, "nrc", NRCParams(), 0, 10, 16),
            reference_key(PREPARED.scene, ReferenceSettings(integrator="pt", max_depth=8))]


def _bump(monkeypatch, method: str) -> None:
    monkeypatch.setitem(methods.METHODS, method,
                        dataclasses.replace(methods.METHODS[method],
                                            version=methods.METHODS[method].version + 1))


def test_every_key_changes_with_the_estimator_version(monkeypatch) -> None:
    before = _keys()
    _bump(monkeypatch, "pt")
    _bump(monkeypatch, "nrc")
    after = _keys()
    assert all(b != a for b, a in zip(before, after, strict=True))


def test_every_key_changes_with_the_metric_version(monkeypatch) -> None:
    import jobs.protocol.references
    import jobs.protocol.spec
    import jobs.protocol.versions

    before = _keys()
    for module in (jobs.protocol.versions, jobs.protocol.spec, jobs.protocol.references):
        monkeypatch.setattr(module, "METRIC_VERSION", 99)
    assert all(b != a for b, a in zip(before, _keys(), strict=True))


def test_a_job_of_the_old_version_is_not_reused(store: Store, monkeypatch) -> None:
    queue = JobQueue(store)
    old, created = queue.submit("render", SPEC.model_dump(mode="json"),
                                spec_key("render", SPEC, "cpu"))
    assert created
    again, created = queue.submit("render", SPEC.model_dump(mode="json"),
                                  spec_key("render", SPEC, "cpu"))
    assert again.id == old.id and not created          # same versions: deduped
    _bump(monkeypatch, "pt")
    new, created = queue.submit("render", SPEC.model_dump(mode="json"),
                                spec_key("render", SPEC, "cpu"))
    assert created and new.id != old.id                # version 3 of pt: a new job


def test_migration_gives_existing_rows_version_1(store: Store) -> None:
    run = store.add_run(run_fields(estimator_version=2, metric_version=2))
    reference = store.add_reference(**reference_fields(estimator_version="pt 2",
                                                       metric_version=2))
    config = alembic_config()
    with store.engine.begin() as conn:
        config.attributes["connection"] = conn
        command.downgrade(config, "0005")
    migrate(store.engine)
    run = store.get_run(run.id)
    assert (run.estimator_version, run.metric_version) == (1, 1)
    reference = store.get_reference(reference.id)
    assert (reference.estimator_version, reference.metric_version) == ("1", 1)
