"""Reproductions of papers' figures run as jobs: the job kind ``reproduce``.

Revision ID: 0012
Revises: 0011
Create Date: 2026-11-29 07:00:00
"""

from collections.abc import Sequence

from alembic import op

revision: str = '0012'
down_revision: str | None = '0011'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_jobs_kind'), type_='check')
        batch_op.create_check_constraint('kind',
                                         "kind IN ('render', 'sweep', 'stage', 'reproduce')")


def downgrade() -> None:
    op.execute("DELETE FROM jobs WHERE kind = 'reproduce'")
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_jobs_kind'), type_='check')
        batch_op.create_check_constraint('kind', "kind IN ('render', 'sweep', 'stage')")
