"""The branch a run's project checkout was on, beside its commit.

``nirc-bench ci`` compares with the latest results of a named commit or branch;
rows stored before this revision have no branch (null).

Revision ID: 0008
Revises: 0007
Create Date: 2026-12-15 10:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0008'
down_revision: str | None = '0007'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('runs', schema=None) as batch_op:
        batch_op.add_column(sa.Column('git_branch', sa.String(), nullable=True))
        batch_op.create_index('ix_runs_git_branch', ['git_branch'], unique=False)


def downgrade() -> None:
    with op.batch_alter_table('runs', schema=None) as batch_op:
        batch_op.drop_index('ix_runs_git_branch')
        batch_op.drop_column('git_branch')
