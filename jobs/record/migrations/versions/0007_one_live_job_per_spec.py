"""Exactly once: at most one queued, running or succeeded job per spec key.

A partial unique index (SQLite and PostgreSQL both support ``WHERE`` on an
index) makes the database refuse a second live job for a spec, so concurrent
identical submissions can no longer both insert (jobs.execution.queue.JobQueue.submit).

Duplicates stored before this revision are merged first: per spec key the job
kept is the oldest succeeded one (it has the result), else the oldest live one;
every other live or succeeded job of that key becomes ``canceled`` with an
error naming the job it duplicates (its run, if any, stays linked), and so do
the unfinished stages of a duplicate sweep. Nothing is deleted.

Revision ID: 0007
Revises: 0006
Create Date: 2026-12-08 10:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0007'
down_revision: str | None = '0006'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_LIVE = ('queued', 'running', 'succeeded')
_WHERE = "status IN ('queued', 'running', 'succeeded')"

_jobs = sa.table('jobs', sa.column('id', sa.Integer), sa.column('parent_id', sa.Integer),
                 sa.column('spec_key', sa.String), sa.column('status', sa.String),
                 sa.column('error', sa.Text), sa.column('cancel_requested', sa.Boolean),
                 sa.column('finished_at', sa.DateTime))


def _cancel(bind: sa.Connection, job_ids: list[int], error: str) -> None:
    bind.execute(_jobs.update().where(_jobs.c.id.in_(job_ids)).values(
        status='canceled', cancel_requested=True, error=error,
        finished_at=sa.func.coalesce(_jobs.c.finished_at, sa.func.current_timestamp())))


def merge_duplicates(bind: sa.Connection) -> int:
    """Cancel all but one live or succeeded job per spec key; returns how many."""
    rows = bind.execute(sa.select(_jobs.c.id, _jobs.c.spec_key, _jobs.c.status)
                        .where(_jobs.c.status.in_(_LIVE)).order_by(_jobs.c.id)).all()
    by_key: dict[str, list[tuple[int, str]]] = {}
    for job_id, key, status in rows:
        by_key.setdefault(key, []).append((job_id, status))
    merged = 0
    for jobs in by_key.values():
        if len(jobs) < 2:
            continue
        keep = min(jobs, key=lambda job: (job[1] != 'succeeded', job[0]))[0]
        for job_id, status in jobs:
            if job_id == keep:
                continue
            _cancel(bind, [job_id], f"merged into job {keep}: a duplicate of the same spec "
                                    f"(was {status}; migration 0007, one job per spec)")
            stages = bind.execute(sa.select(_jobs.c.id).where(
                _jobs.c.parent_id == job_id,
                _jobs.c.status.in_(('queued', 'running')))).scalars().all()
            if stages:
                _cancel(bind, list(stages), f"its sweep job {job_id} was merged into job {keep}")
            merged += 1
    return merged


def upgrade() -> None:
    merge_duplicates(op.get_bind())
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.create_index('uq_jobs_live_spec_key', ['spec_key'], unique=True,
                              sqlite_where=sa.text(_WHERE), postgresql_where=sa.text(_WHERE))


def downgrade() -> None:
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_index('uq_jobs_live_spec_key')
