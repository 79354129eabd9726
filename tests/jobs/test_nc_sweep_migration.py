"""The store migration that re-keys the N_c sweeps stored as a study of their own
(jobs/record/migrations/versions/0011_nc_sweeps_as_parameter_sweeps.py): a stored
sweep, its sweep job and its stage job come out as the code of today writes them."""

from __future__ import annotations

from typing import Any

from alembic import command
from sqlalchemy import select
from sqlalchemy.orm import Session

from jobs.execution.graph import sweep_stages
from jobs.execution.queue import spec_key
from jobs.protocol.versions import sweep_estimator_versions
from jobs.record.db import alembic_config
from jobs.record.models import Job, Sweep
from jobs.record.store import Store
from metrics import METRIC_VERSION
from tests.jobs.test_job import GOLDEN, SWEEPS

#: The golden N_c sweep as the code before stored it (its keys: tests/jobs/test_job.py's
#: values before the N_c sweep became a parameter sweep).
OLD_NC_SPEC = {**SWEEPS["eps"].model_dump(mode="json"), "eps": None, "nc": [1, 2],
               "termination": "sph", "params": {"sph_c": 0.02}}
OLD_SPEC_KEY = "f8c06a10deecc436db4b7559cdf6815ffe9e91a308f438c9703baf3bf8fe5d16"
OLD_QUEUE_KEY = "7eb100b9d6dee1d0cd56e3267b09a1107f3b495ea0c18d9ff18b2a9c98295712"


def _migrate_again(store: Store, rows: list[Any]) -> None:
    """Back to the revision before, store ``rows`` there, and up again."""
    config = alembic_config()
    with store.engine.begin() as conn:
        config.attributes["connection"] = conn
        command.downgrade(config, "0010")
    with Session(store.engine) as session, session.begin():
        session.add_all(rows)
    with store.engine.begin() as conn:
        config.attributes["connection"] = conn
        command.upgrade(config, "head")


def _sweep(key: str, spec: dict[str, Any], kind: str = "nc", **values: Any) -> Sweep:
    return Sweep(key=key, kind=kind, scene_name="cornell-box", scene_fingerprint="f",
                 spec=spec, status="succeeded", device_key="device",
                 estimator_versions=sweep_estimator_versions(spec["methods"]),
                 metric_version=METRIC_VERSION, **values)


def test_stored_nc_sweeps_are_rekeyed_as_parameter_sweeps(store: Store) -> None:
    new = SWEEPS["nc"]
    assert OLD_SPEC_KEY != new.key("device")
    sweep = _sweep(OLD_SPEC_KEY, OLD_NC_SPEC, result={
        "kind": "nc", "key": OLD_SPEC_KEY, "parameter": None, "rows": [{"nc": 1}, {"nc": 2}]})
    # Planted: a key its stated versions do not give is left as it was.
    stale = _sweep("0" * 64, {**OLD_NC_SPEC, "seeds": 3})
    eps = _sweep(GOLDEN["sweep-spec eps"], SWEEPS["eps"].model_dump(mode="json"), kind="eps")
    job = Job(id=1, kind="sweep", spec=OLD_NC_SPEC, spec_key=OLD_QUEUE_KEY, device_class="cpu",
              status="queued")
    stage = Job(id=2, kind="stage", parent_id=1, spec_key="job-1-stage-nc 2",
                idempotency_key="job-1-stage-nc 2", device_class="cpu", status="queued",
                spec={"sweep": OLD_NC_SPEC, "name": "nc 2",
                      "task": {"stage": "nc-point", "nc": 2}})
    _migrate_again(store, [sweep, stale, eps, job, stage])

    with Session(store.engine) as session:
        sweeps = {row.key: row for row in session.scalars(select(Sweep))}
        jobs = {row.id: row for row in session.scalars(select(Job))}
    stored = sweeps[new.key("device")]
    assert stored.spec == new.model_dump(mode="json") and stored.kind == new.kind
    assert stored.result == {"kind": "parameter", "key": new.key("device"), "parameter": "nc",
                             "rows": [{"nc": 1, "value": 1}, {"nc": 2, "value": 2}]}
    assert sweeps["0" * 64].kind == "parameter"   # re-formed, not re-keyed
    assert sweeps[GOLDEN["sweep-spec eps"]].spec == SWEEPS["eps"].model_dump(mode="json")
    assert jobs[1].spec == new.model_dump(mode="json")
    assert jobs[1].spec_key == spec_key("sweep", new, "cpu") == GOLDEN["idempotency sweep nc"]
    stage_of_2 = next(s for s in sweep_stages(new) if s.task.get("value") == 2)
    assert jobs[2].spec == {"sweep": new.model_dump(mode="json"), "name": stage_of_2.name,
                            "task": stage_of_2.task}
    assert jobs[2].spec_key == jobs[2].idempotency_key == f"job-1-stage-{stage_of_2.name}"
