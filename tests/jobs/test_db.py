"""Engine setup and migrations: SQLite pragmas, idempotent and concurrent upgrades,
and the migration history agreeing with the models."""

import logging.config
import sqlite3
import threading
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from pathlib import Path

import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.config import Config
from alembic.migration import MigrationContext
from sqlalchemy import inspect, text
from sqlalchemy.engine import make_url

from jobs.record.config import Settings
from jobs.record.db import (
    MIGRATIONS_DIR,
    SQLITE_BUSY_TIMEOUT_MS,
    SchemaVersionError,
    make_engine,
    migrate,
)
from jobs.record.models import Base
from jobs.record.store import Store
from tests.pg import postgres_database

#: These tests migrate the database: an empty one, not the copy of a migrated one that
#: the other store tests start from (tests/jobs/conftest.py, tests/pg.py).
pytestmark = pytest.mark.empty_database

TABLES = {"reference_renders", "runs", "seed_results", "artifacts", "cache_snapshots", "sweeps",
          "jobs", "api_keys", "login_sessions"}


def test_sqlite_pragmas(sqlite_store: Store) -> None:
    store = sqlite_store
    with store.engine.connect() as conn:
        assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
        assert conn.exec_driver_sql("PRAGMA busy_timeout").scalar() == SQLITE_BUSY_TIMEOUT_MS
        assert conn.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1


def test_make_engine_creates_parent_folder(tmp_path: Path) -> None:
    engine = make_engine(f"sqlite:///{tmp_path / 'a' / 'b' / 'x.db'}")
    with engine.connect() as conn:
        conn.execute(text("SELECT 1"))
    engine.dispose()
    assert (tmp_path / "a" / "b" / "x.db").is_file()


def test_the_database_starts_empty(settings: Settings, migrated_sqlite: Path) -> None:
    """The migrations below run on an empty database; the copy of a migrated one that
    the other store tests start from (planted here) has the tables already."""
    engine = make_engine(settings.database_url)
    assert inspect(engine).get_table_names() == []
    engine.dispose()
    postgresql = make_url(settings.database_url).get_backend_name() == "postgresql"
    with postgres_database() if postgresql else nullcontext(f"sqlite:///{migrated_sqlite}") \
            as copy_url:
        engine = make_engine(copy_url)
        assert TABLES <= set(inspect(engine).get_table_names())
        engine.dispose()


def test_fresh_database_gets_all_tables(store: Store) -> None:
    tables = set(inspect(store.engine).get_table_names())
    assert tables == TABLES | {"alembic_version"}
    indexes = {ix["name"] for ix in inspect(store.engine).get_indexes("runs")}
    assert {"ix_runs_scene_fingerprint_method", "ix_runs_device_key"} <= indexes


def test_migrating_twice_is_a_no_op(store: Store) -> None:
    with store.engine.connect() as conn:
        before = conn.execute(text("SELECT version_num FROM alembic_version")).scalars().all()
    migrate(store.engine)
    migrate(store.engine)
    with store.engine.connect() as conn:
        after = conn.execute(text("SELECT version_num FROM alembic_version")).scalars().all()
    assert before == after == ["0012"]


def test_migrations_match_models(store: Store) -> None:
    with store.engine.connect() as conn:
        context = MigrationContext.configure(conn, opts={"compare_type": True})
        assert compare_metadata(context, Base.metadata) == []


def test_concurrent_migrations_on_a_fresh_database(tmp_path: Path) -> None:
    # Several workers starting at once must not race on CREATE TABLE.
    url = f"sqlite:///{tmp_path / 'shared.db'}"

    def start() -> None:
        engine = make_engine(url)
        try:
            migrate(engine)
        finally:
            engine.dispose()

    with ThreadPoolExecutor(max_workers=4) as pool:
        for future in [pool.submit(start) for _ in range(4)]:
            future.result()
    engine = make_engine(url)
    assert TABLES <= set(inspect(engine).get_table_names())
    engine.dispose()


def test_wal_switch_waits_for_a_writer_on_a_fresh_database(tmp_path: Path) -> None:
    # SQLite refuses the switch to WAL at once (no busy handler) while another
    # connection holds the write lock on a database still in rollback mode.
    path = tmp_path / "fresh.db"
    writer = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
    writer.execute("BEGIN IMMEDIATE")
    writer.execute("CREATE TABLE t (x)")
    release = threading.Timer(0.3, writer.execute, args=("COMMIT",))
    release.start()
    engine = make_engine(f"sqlite:///{path}")
    try:
        with engine.connect() as conn:
            assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
    finally:
        release.join()
        writer.close()
        engine.dispose()


def test_newer_schema_is_explained(store: Store) -> None:
    with store.engine.begin() as conn:
        conn.execute(text("UPDATE alembic_version SET version_num = '9999'"))
    with pytest.raises(SchemaVersionError, match="newer nirc-bench"):
        migrate(store.engine)


def test_downgrade_and_upgrade_again(store: Store) -> None:
    from jobs.record.db import alembic_config

    config = alembic_config()
    with store.engine.begin() as conn:
        config.attributes["connection"] = conn
        command.downgrade(config, "base")
    assert set(inspect(store.engine).get_table_names()) == {"alembic_version"}
    migrate(store.engine)
    assert TABLES <= set(inspect(store.engine).get_table_names())


def test_command_line_configuration(settings: Settings, monkeypatch: pytest.MonkeyPatch) -> None:
    # The alembic.ini used to write new revisions reaches the configured database.
    monkeypatch.setenv("NIRC_BENCH_DATA_DIR", str(settings.data_dir))
    # Keep the ini's logging setup out of the test process.
    monkeypatch.setattr(logging.config, "fileConfig", lambda *args, **kwargs: None)
    command.upgrade(Config(str(MIGRATIONS_DIR / "alembic.ini")), "head")
    engine = make_engine(f"sqlite:///{settings.data_dir / 'nirc-bench.db'}")
    assert TABLES <= set(inspect(engine).get_table_names())
    engine.dispose()


def test_an_existing_database_file_is_never_opened_outside_sqlite(tmp_path, monkeypatch):
    """Closing any descriptor of a file drops every POSIX lock the process holds on it,
    SQLite's included: opening the store again (as every job of the embedded worker
    does) must not touch an existing database file (it gave 'disk I/O error')."""
    import os

    from jobs.record import db

    database = tmp_path / "data" / "nirc-bench.db"
    db._create_private_file(database)
    assert database.stat().st_mode & 0o777 == 0o600
    opened = []                                  # descriptors actually obtained

    def recording_open(path, *args):
        fd = real_open(path, *args)
        opened.append(os.fspath(path))
        return fd

    real_open = os.open
    monkeypatch.setattr(os, "open", recording_open)
    db._create_private_file(database)
    assert os.fspath(database) not in opened
