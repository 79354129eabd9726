"""Job owners, admin keys and server-side dashboard sessions.

A job records the API key that submitted it (``owner_key_id``; null for the CLI's
jobs and for jobs stored before this revision, which only an admin key may cancel
over REST). ``api_keys.admin`` marks keys that may cancel other keys' jobs. The
dashboard's login cookie holds a session token whose digest is a ``login_sessions``
row, no longer the API key itself.

Revision ID: 0009
Revises: 0008
Create Date: 2027-01-10 10:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0009'
down_revision: str | None = '0008'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # Columns are added in place, never by rebuilding a table: on SQLite a rebuild
    # drops the old table, and the ON DELETE CASCADE of a sweep's stage jobs would
    # empty them from the copy. (So owner_key_id has no foreign key: API keys are
    # never deleted, and SQLite cannot add one in place.)
    op.add_column('api_keys', sa.Column('admin', sa.Boolean(), nullable=False,
                                        server_default=sa.text('false')))
    op.add_column('jobs', sa.Column('owner_key_id', sa.Integer(), nullable=True))
    op.create_index(op.f('ix_jobs_owner_key_id'), 'jobs', ['owner_key_id'], unique=False)
    op.create_table('login_sessions',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('digest', sa.String(), nullable=False),
    sa.Column('api_key_id', sa.Integer(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('expires_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['api_key_id'], ['api_keys.id'],
                            name=op.f('fk_login_sessions_api_key_id_api_keys'),
                            ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_login_sessions')),
    sa.UniqueConstraint('digest', name=op.f('uq_login_sessions_digest'))
    )
    with op.batch_alter_table('login_sessions', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_login_sessions_api_key_id'), ['api_key_id'],
                              unique=False)
        batch_op.create_index(batch_op.f('ix_login_sessions_expires_at'), ['expires_at'],
                              unique=False)


def downgrade() -> None:
    op.drop_table('login_sessions')
    op.drop_index(op.f('ix_jobs_owner_key_id'), table_name='jobs')
    op.drop_column('jobs', 'owner_key_id')
    op.drop_column('api_keys', 'admin')
