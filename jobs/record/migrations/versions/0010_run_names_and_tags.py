"""Run names and tags: a label a user gives a run, and key=value tags to find it by.

Revision ID: 0010
Revises: 0009
Create Date: 2027-02-01 10:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0010'
down_revision: str | None = '0009'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # In place (no table rebuild), as in 0009.
    op.add_column('runs', sa.Column('name', sa.String(), nullable=True))
    op.add_column('runs', sa.Column('tags', sa.JSON(), nullable=False,
                                    server_default=sa.text("'{}'")))
    op.create_index(op.f('ix_runs_name'), 'runs', ['name'], unique=False)


def downgrade() -> None:
    op.drop_index(op.f('ix_runs_name'), table_name='runs')
    op.drop_column('runs', 'tags')
    op.drop_column('runs', 'name')
