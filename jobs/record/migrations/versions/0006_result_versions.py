"""Estimator and metric-definition versions of every stored result.

Rows stored before this revision get version 1 (everything computed before the
versions were recorded); new rows state the versions they were computed under.

Revision ID: 0006
Revises: 0005
Create Date: 2026-12-01 10:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0006'
down_revision: str | None = '0005'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_TABLES = ('reference_renders', 'runs', 'cache_snapshots')


def upgrade() -> None:
    for table in _TABLES:
        estimator = sa.String() if table == 'reference_renders' else sa.Integer()
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.add_column(sa.Column('estimator_version', estimator, server_default='1',
                                          nullable=False))
            batch_op.add_column(sa.Column('metric_version', sa.Integer(), server_default='1',
                                          nullable=False))
    with op.batch_alter_table('sweeps', schema=None) as batch_op:
        batch_op.add_column(sa.Column('estimator_versions', sa.JSON(), nullable=True))
        batch_op.add_column(sa.Column('metric_version', sa.Integer(), server_default='1',
                                      nullable=False))


def downgrade() -> None:
    for table in ('sweeps', *reversed(_TABLES)):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.drop_column('metric_version')
            batch_op.drop_column('estimator_versions' if table == 'sweeps'
                                 else 'estimator_version')
