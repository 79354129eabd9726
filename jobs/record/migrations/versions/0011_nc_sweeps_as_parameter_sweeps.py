"""N_c sweeps stored as parameter sweeps over ``nc``.

An N_c sweep was a study of its own: its spec held ``nc`` (without eps) and a
top-level ``termination`` (NIRC's default policy unless given), its points were the
stage tasks ``nc-point``. It is now a parameter sweep over NIRC's ``nc`` with NIRC
alone as its method and the termination policy one of NIRC's parameters where it is
not the default (jobs/protocol/spec.py), so its spec dumps, and its spec keys hash,
otherwise. This revision rewrites what was stored in the old form to the new one:

- ``sweeps``: the spec, the kind ('parameter'), the key and the result's kind, key,
  parameter and the rows' values;
- ``jobs``: a sweep job's spec and its queue key (``spec_key``); its stage jobs' copy
  of the spec, their task (``parameter-point`` of nirc), name and keys.

A key is rewritten only where the old one is recomputed from the row under the
versions it states (a sweep's own, or a job's sweep's, else today's): a key that is
not (written before versions were recorded) can match no new submission anyway. A
key that another row holds already is left as it was. The points (runs) keep their
keys: an N_c sweep's points are keyed as before.

The key formulas below are those of this revision, frozen here.

Revision ID: 0011
Revises: 0010
Create Date: 2027-02-08 10:00:00
"""

from collections.abc import Sequence
from typing import Any

import sqlalchemy as sa
from alembic import op

revision: str = '0011'
down_revision: str | None = '0010'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

#: The method an N_c sweep varied and its parameter (the only one of either, then).
METHOD, PARAMETER = 'nirc', 'nc'

_SWEEPS = sa.table('sweeps', sa.column('id', sa.Integer), sa.column('key', sa.String),
                   sa.column('kind', sa.String), sa.column('spec', sa.JSON),
                   sa.column('result', sa.JSON), sa.column('device_key', sa.String),
                   sa.column('estimator_versions', sa.JSON),
                   sa.column('metric_version', sa.Integer))
_JOBS = sa.table('jobs', sa.column('id', sa.Integer), sa.column('kind', sa.String),
                 sa.column('parent_id', sa.Integer), sa.column('spec', sa.JSON),
                 sa.column('spec_key', sa.String), sa.column('idempotency_key', sa.String),
                 sa.column('device_class', sa.String), sa.column('sweep_id', sa.Integer))


def _default_termination() -> Any:
    from renderers.methods import METHODS

    return METHODS[METHOD].params.model_fields['termination'].default


def new_spec(spec: Any) -> dict[str, Any] | None:
    """The parameter-sweep form of an N_c sweep's stored spec (None: not one)."""
    if (not isinstance(spec, dict) or spec.get('nc') is None or spec.get('eps') is not None
            or spec.get('parameter') is not None):
        return None
    new = {name: value for name, value in spec.items() if name != 'termination'}
    new.update(nc=None, methods=[METHOD],
               parameter={'name': PARAMETER, 'values': list(spec['nc'])})
    termination = spec.get('termination')
    if termination is not None and termination != _default_termination():
        new['params'] = {**(spec.get('params') or {}), 'termination': termination}
    return new


def _keyed(spec: dict[str, Any]) -> dict[str, Any]:
    """A dumped sweep spec as its keys see it (a false allow_loaded left out)."""
    return {name: value for name, value in spec.items()
            if not (name == 'allow_loaded' and value is False)}


def _digest(*parts: Any) -> str:
    from renderers.seeding import digest

    return digest(*parts)


def _versions(estimator_versions: dict[str, Any], metric_version: Any,
              methods: list[str]) -> dict[str, Any]:
    return {'estimator_versions': {m: estimator_versions.get(m) for m in methods},
            'metric_version': metric_version}


def _rekeyed(kind: str, old: dict[str, Any], new: dict[str, Any], where: str, stored: str,
             candidates: list[tuple[dict[str, Any], Any]], taken: set[str]) -> str:
    """The key of ``new`` under the first versions that give ``stored`` for ``old``
    (``stored`` itself where none does, or where the new key is taken)."""
    for estimator_versions, metric_version in candidates:
        if not isinstance(estimator_versions, dict):
            continue
        versions = _versions(estimator_versions, metric_version, old.get('methods', []))
        if _digest(kind, _keyed(old), where, versions) == stored:
            key = _digest(kind, _keyed(new), where,
                          _versions(estimator_versions, metric_version, [METHOD]))
            return stored if key in taken else key
    return stored


def _today() -> tuple[dict[str, Any], Any]:
    from metrics import METRIC_VERSION
    from renderers.methods import METHODS

    return {name: method.version for name, method in METHODS.items()}, METRIC_VERSION


def _new_result(result: Any, key: str) -> Any:
    if not isinstance(result, dict) or 'rows' not in result:
        return result
    rows = [{**row, 'value': row.get('nc')} for row in result['rows']]
    return {**result, 'kind': 'parameter', 'key': key, 'parameter': PARAMETER, 'rows': rows}


def _upgrade_sweeps(bind: Any) -> dict[int, tuple[dict[str, Any], Any]]:
    """Re-key the N_c sweeps; returns every sweep's versions by id (for its jobs)."""
    rows = bind.execute(sa.select(_SWEEPS)).mappings().all()
    taken = {row['key'] for row in rows}
    for row in rows:
        spec = new_spec(row['spec'])
        if spec is None:
            continue
        key = _rekeyed('sweep-spec', row['spec'], spec, row['device_key'], row['key'],
                       [(row['estimator_versions'], row['metric_version'])], taken)
        taken.add(key)
        bind.execute(_SWEEPS.update().where(_SWEEPS.c.id == row['id']).values(
            spec=spec, kind='parameter', key=key, result=_new_result(row['result'], key)))
    return {row['id']: (row['estimator_versions'], row['metric_version']) for row in rows}


def _stage(job: Any, parent_spec: dict[str, Any]) -> dict[str, Any]:
    """A stage job of a re-formed sweep job: its copy of the spec, its task, name, keys."""
    task = job['spec'].get('task') or {}
    values: dict[str, Any] = {'spec': {**job['spec'], 'sweep': parent_spec}}
    if task.get('stage') == 'nc-point':
        name = f"{METHOD} {PARAMETER}={task['nc']}"
        key = f"job-{job['parent_id']}-stage-{name}"
        values['spec'] = {**values['spec'], 'name': name,
                          'task': {'stage': 'parameter-point', 'method': METHOD,
                                   'value': task['nc']}}
        values.update(spec_key=key, idempotency_key=key)
    return values


def _upgrade_jobs(bind: Any, sweep_versions: dict[int, tuple[dict[str, Any], Any]]) -> None:
    jobs = bind.execute(sa.select(_JOBS)).mappings().all()
    taken = {job['spec_key'] for job in jobs}
    specs: dict[int, dict[str, Any]] = {}
    for job in jobs:
        spec = new_spec(job['spec']) if job['kind'] == 'sweep' else None
        if spec is None:
            continue
        specs[job['id']] = spec
        candidates = [sweep_versions[job['sweep_id']]] if job['sweep_id'] in sweep_versions else []
        key = _rekeyed('sweep', job['spec'], spec, job['device_class'], job['spec_key'],
                       [*candidates, _today()], taken)
        taken.add(key)
        bind.execute(_JOBS.update().where(_JOBS.c.id == job['id']).values(spec=spec,
                                                                          spec_key=key))
    for job in jobs:
        if job['kind'] == 'stage' and job['parent_id'] in specs:
            bind.execute(_JOBS.update().where(_JOBS.c.id == job['id']).values(
                **_stage(job, specs[job['parent_id']])))


def upgrade() -> None:
    bind = op.get_bind()
    _upgrade_jobs(bind, _upgrade_sweeps(bind))


def downgrade() -> None:
    # The rows stay in the parameter-sweep form, which the code before this revision
    # does not run as an N_c sweep; nothing of the schema changed.
    pass
