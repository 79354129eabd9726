"""Reproductions of papers' figures run as jobs: the job kind ``reproduce``.

SQLite changes a CHECK constraint by copying the table and dropping the old one; with
foreign keys on, that drop deletes the old rows one by one, and ``ON DELETE CASCADE``
would delete every stage job from the copy (its ``parent_id`` names ``jobs``). The
parents are therefore set aside and cleared first, and restored on the copy.

Revision ID: 0012
Revises: 0011
Create Date: 2026-11-29 07:00:00
"""

from collections.abc import Sequence

from alembic import op

KINDS = "('render', 'sweep', 'stage', 'reproduce')"
KINDS_BEFORE = "('render', 'sweep', 'stage')"


def _set_kinds(kinds: str) -> None:
    op.execute("CREATE TEMPORARY TABLE parents_0012 AS "
               "SELECT id, parent_id FROM jobs WHERE parent_id IS NOT NULL")
    op.execute("UPDATE jobs SET parent_id = NULL WHERE parent_id IS NOT NULL")
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_jobs_kind'), type_='check')
        batch_op.create_check_constraint('kind', f"kind IN {kinds}")
    op.execute("UPDATE jobs SET parent_id = (SELECT parent_id FROM parents_0012 "
               "WHERE parents_0012.id = jobs.id) "
               "WHERE id IN (SELECT id FROM parents_0012)")
    op.execute("DROP TABLE parents_0012")

revision: str = '0012'
down_revision: str | None = '0011'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    _set_kinds(KINDS)


def downgrade() -> None:
    op.execute("DELETE FROM jobs WHERE kind = 'reproduce'")
    _set_kinds(KINDS_BEFORE)
