"""Fixtures for the job-store tests: a migrated store, on SQLite and on PostgreSQL.

``settings`` / ``store`` run every test that uses them twice: on a SQLite file in a
temporary folder, and on a fresh database of the PostgreSQL test server
(``scripts/test_postgres.sh``, see ``tests/setup_services.py``). Each starts as a copy
of a database migrated once per session; the tests marked ``empty_database`` (those
of migrating) get an empty one.
"""

from collections.abc import Iterator
from pathlib import Path

import pytest

from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.record.store import Store
from tests.pg import postgres_database


@pytest.fixture(params=["sqlite", "postgresql"])
def settings(request, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Settings]:
    # A database URL in the developer's environment must not redirect the tests.
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    if request.param == "sqlite":
        yield Settings(data_dir=request.getfixturevalue("data_folder"))
        return
    # A copy of a migrated database (tests/pg.py), empty for the tests of migrating.
    empty = request.node.get_closest_marker("empty_database") is not None
    with postgres_database(migrated=not empty) as url:
        yield Settings(data_dir=tmp_path / "data", database_url=url)


@pytest.fixture
def store(settings: Settings) -> Iterator[Store]:
    store = open_store(settings)
    yield store
    store.close()


@pytest.fixture
def sqlite_store(data_folder: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Store]:
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    store = open_store(Settings(data_dir=data_folder))
    yield store
    store.close()
