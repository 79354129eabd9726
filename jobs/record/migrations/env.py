"""Alembic environment of the job store.

At run time ``jobs.record.db.migrate`` builds the Alembic config in code and passes
its open connection in ``config.attributes["connection"]``, so migrations run
inside the caller's transaction (and lock). From the command line, for writing
new revisions, the database comes from the usual settings::

    NIRC_BENCH_DATA_DIR=/tmp/scratch alembic -c jobs/record/migrations/alembic.ini \
        revision --autogenerate --rev-id 0002 -m "what changed"
"""

from logging.config import fileConfig
from typing import Any

from alembic import context
from alembic.autogenerate.api import AutogenContext
from sqlalchemy import Connection

from jobs.record.models import Base, UTCDateTime

config = context.config
target_metadata = Base.metadata


def _render_item(type_: str, obj: Any, autogen_context: AutogenContext) -> str | bool:
    # Revisions must not import jobs.record.models (they are frozen history, the models
    # move on); UTCDateTime only converts values, so its column is a DateTime.
    if type_ == "type" and isinstance(obj, UTCDateTime):
        return "sa.DateTime(timezone=True)"
    return False


def _configure(connection: Connection) -> None:
    sqlite = connection.dialect.name == "sqlite"
    context.configure(
        connection=connection,
        target_metadata=target_metadata,
        # SQLite cannot ALTER most things; batch mode rebuilds the table instead.
        render_as_batch=sqlite,
        # jobs.record.db makes SQLAlchemy emit BEGIN on SQLite, so DDL is transactional
        # there too (Alembic assumes not, after the sqlite3 driver's default).
        transactional_ddl=True if sqlite else None,
        compare_type=True,
        render_item=_render_item,
    )


def run_migrations_offline() -> None:
    """Emit SQL to stdout (``alembic upgrade --sql``) without a database."""
    from jobs.record.config import get_settings

    context.configure(
        url=config.get_main_option("sqlalchemy.url") or get_settings().database_url,
        target_metadata=target_metadata,
        literal_binds=True,
        dialect_opts={"paramstyle": "named"},
    )
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        _configure(connection)
        with context.begin_transaction():
            context.run_migrations()
        return

    # Command-line use: only here may we configure logging, since a library
    # call must not replace the application's logging setup.
    if config.config_file_name is not None:
        fileConfig(config.config_file_name, disable_existing_loggers=False)
    from jobs.record.config import get_settings
    from jobs.record.db import make_engine

    engine = make_engine(config.get_main_option("sqlalchemy.url") or get_settings().database_url)
    try:
        with engine.begin() as connection:
            _configure(connection)
            with context.begin_transaction():
                context.run_migrations()
    finally:
        engine.dispose()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
