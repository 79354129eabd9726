"""Engine creation, schema migration at start, and ``open_store``.

SQLite (the embedded default) is tuned for several processes sharing one file
(the CLI, local-cluster workers, the service): WAL so readers never block the
writer, ``busy_timeout`` so writers wait for each other instead of failing,
foreign keys on (SQLite leaves them off per connection), and transactions begun
by SQLAlchemy rather than the sqlite3 driver so that DDL is transactional and
a migration is never half-applied. PostgreSQL URLs need none of this.

Migrations run programmatically on every ``open_store``: the Alembic
environment in ``jobs/record/migrations`` is configured in code, so no alembic.ini is
needed at run time.
"""

import os
import sqlite3
import time
from functools import cache
from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from alembic.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Connection, Engine, create_engine, event, text
from sqlalchemy.engine import URL, make_url
from sqlalchemy.exc import DBAPIError

from jobs.record.artifacts import PRIVATE_FILE_MODE, make_private_dir
from jobs.record.config import Settings, get_settings
from jobs.record.store import BEGIN_IMMEDIATE_OPTION, Store

MIGRATIONS_DIR = Path(__file__).resolve().with_name("migrations")
SQLITE_BUSY_TIMEOUT_MS = 30_000
# Arbitrary constant ("nirc") naming the PostgreSQL advisory lock that serializes
# migrations when several machines start at once.
_PG_MIGRATION_LOCK = 0x6E697263


class SchemaVersionError(RuntimeError):
    """The database was migrated by a newer nirc-bench than the one running."""


def make_engine(url: str | URL, lock_timeout_s: float | None = None) -> Engine:
    """An engine for ``url``; SQLite files get their folder, WAL and busy_timeout.

    ``lock_timeout_s`` (default :data:`SQLITE_BUSY_TIMEOUT_MS`): how long a statement
    waits for a lock another connection holds before it fails — SQLite's busy_timeout,
    PostgreSQL's lock_timeout (which otherwise waits for ever: a held table lock would
    hang every runner's heartbeat instead of letting it give the job up)."""
    url = make_url(url)
    timeout_ms = round(lock_timeout_s * 1000) if lock_timeout_s else SQLITE_BUSY_TIMEOUT_MS
    if url.get_backend_name() != "sqlite":
        # Long-lived workers outlive server-side idle timeouts; re-check on checkout.
        connect_args = ({"options": f"-c lock_timeout={timeout_ms}"}
                        if url.get_backend_name() == "postgresql" else {})
        return create_engine(url, pool_pre_ping=True, connect_args=connect_args)
    database = url.database
    if database and database != ":memory:" and not url.query.get("uri"):
        _create_private_file(Path(database).expanduser())
    engine = create_engine(url)
    event.listen(engine, "connect",
                 lambda connection, record: _sqlite_on_connect(connection, timeout_ms))
    event.listen(engine, "begin", _sqlite_on_begin)
    return engine


def _create_private_file(path: Path) -> None:
    """The SQLite file and its folder, owner-only (0600 in 0700) if they are new.

    SQLite would create the file with the process's umask (0644 typically); created
    empty first, it is a valid empty database, and SQLite gives its -wal and -shm
    files the database file's mode."""
    make_private_dir(path.parent)
    # Never open an existing database file here: closing any descriptor of a file
    # drops every POSIX lock this process holds on it, including those of SQLite's
    # own open connections (measured: 'disk I/O error' in the next transaction of
    # the service's embedded worker). O_EXCL only ever creates a new, empty file.
    try:
        os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, PRIVATE_FILE_MODE))
    except FileExistsError:
        pass


def _sqlite_on_connect(dbapi_connection: Any, busy_timeout_ms: int) -> None:
    # Take transaction control away from the sqlite3 driver, whose legacy mode
    # runs DDL and SELECTs outside any transaction; _sqlite_on_begin emits BEGIN.
    dbapi_connection.isolation_level = None
    cursor = dbapi_connection.cursor()
    try:
        # busy_timeout first: switching to WAL needs a lock another process may hold.
        cursor.execute(f"PRAGMA busy_timeout = {int(busy_timeout_ms)}")
        _switch_to_wal(cursor)
        cursor.execute("PRAGMA foreign_keys = ON")
    finally:
        cursor.close()


def _switch_to_wal(cursor: Any) -> None:
    """``PRAGMA journal_mode = WAL``, retried while another connection blocks it.

    The switch reads the file (shared lock) and then needs it exclusively. When
    another connection holds the write lock at that moment, SQLite reports
    "database is locked" at once instead of calling the busy handler (waiting
    could deadlock), so ``busy_timeout`` does not cover it; this only happens
    while a fresh database is being created by several processes at once.
    """
    deadline = time.monotonic() + SQLITE_BUSY_TIMEOUT_MS / 1000
    delay_s = 0.005
    while True:
        try:
            cursor.execute("PRAGMA journal_mode = WAL")
            return
        except sqlite3.OperationalError as error:
            if "locked" not in str(error) or time.monotonic() > deadline:
                raise
        time.sleep(delay_s)
        delay_s = min(2 * delay_s, 0.2)


def _sqlite_on_begin(connection: Connection) -> None:
    # Writers ask for IMMEDIATE to queue on busy_timeout for the write lock; a
    # deferred transaction that reads first would instead fail at once with
    # "database is locked" if another writer committed in between.
    immediate = connection.get_execution_options().get(BEGIN_IMMEDIATE_OPTION, False)
    connection.exec_driver_sql("BEGIN IMMEDIATE" if immediate else "BEGIN")


def alembic_config() -> Config:
    """The Alembic configuration of the job store, built in code."""
    config = Config()
    # ConfigParser interpolates '%', which may occur in an install path.
    config.set_main_option("script_location", str(MIGRATIONS_DIR).replace("%", "%%"))
    return config


@cache
def _revisions() -> tuple[frozenset[str], frozenset[str]]:
    """(head revisions, every revision) of the project's migrations, read once per process:
    reading them loads every migration file (~40 ms, which every job's store paid)."""
    script = ScriptDirectory.from_config(alembic_config())
    return (frozenset(script.get_heads()),
            frozenset(revision.revision for revision in script.walk_revisions()))


def migrate(engine: Engine) -> None:
    """Upgrade the database to the newest schema; a no-op when it is current.

    Safe when several processes start at once: the check and the upgrade run in
    one transaction holding SQLite's write lock (or a PostgreSQL advisory lock),
    so the later process waits and then finds nothing to do.
    """
    heads, known = _revisions()
    # The common case, a current schema, is settled by reading Alembic's version table
    # without a lock: every job's runner checks (jobs/execution/runner.py), and taking
    # SQLite's write lock and building Alembic's migration context for it cost ~9 ms a
    # job and queued each check behind the jobs being written. Anything else (a new
    # database, an older or a newer schema) is decided again under the lock.
    try:
        with engine.connect() as connection:
            stored = {row[0] for row in connection.exec_driver_sql(
                "SELECT version_num FROM alembic_version")}
    except DBAPIError:      # no version table yet: a new database
        stored = set()
    if stored == heads:
        return
    with engine.execution_options(**{BEGIN_IMMEDIATE_OPTION: True}).begin() as connection:
        if connection.dialect.name == "postgresql":
            # A migration on another machine may take long: wait for it, whatever the
            # engine's lock timeout.
            connection.execute(text("SET LOCAL lock_timeout = 0"))
            connection.execute(
                text("SELECT pg_advisory_xact_lock(:key)"), {"key": _PG_MIGRATION_LOCK}
            )
        if _current_heads(connection, engine, known) == heads:
            return
        # env.py runs the migrations on this connection, inside this transaction.
        config = alembic_config()
        config.attributes["connection"] = connection
        command.upgrade(config, "head")


def _current_heads(connection: Connection, engine: Engine, known: frozenset[str]) -> set[str]:
    """The database's schema revisions; refused when one is unknown to this version."""
    current = set(MigrationContext.configure(connection).get_current_heads())
    if current - known:
        raise SchemaVersionError(
            f"the database at {engine.url.render_as_string(hide_password=True)} has "
            f"schema revision {', '.join(sorted(current - known))}, which this "
            "version of nirc-bench does not know: it was created by a newer "
            "nirc-bench. Upgrade nirc-bench or point NIRC_BENCH_DATABASE_URL / "
            "NIRC_BENCH_DATA_DIR at another database."
        )
    return current


def open_store(settings: Settings | None = None) -> Store:
    """Connect to the configured database, migrate it to head, and return a Store."""
    settings = settings or get_settings()
    assert settings.database_url is not None  # filled in by Settings validation
    engine = make_engine(settings.database_url, settings.db_lock_timeout_s)
    try:
        migrate(engine)
    except BaseException:
        engine.dispose()
        raise
    return Store(engine)
