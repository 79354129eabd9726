"""Fixtures for the job-store tests: a migrated store, on SQLite and on PostgreSQL.

``settings`` / ``store`` run every test that uses them twice: on a SQLite file in a
temporary folder, and on a fresh database of the PostgreSQL test server
(``scripts/test_postgres.sh``, see ``tests/setup_services.py``).
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
        yield Settings(data_dir=tmp_path / "data")
        return
    with postgres_database() as url:
        yield Settings(data_dir=tmp_path / "data", database_url=url)


@pytest.fixture
def store(settings: Settings) -> Iterator[Store]:
    store = open_store(settings)
    yield store
    store.close()


@pytest.fixture
def sqlite_store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Store]:
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    store = open_store(Settings(data_dir=tmp_path / "data"))
    yield store
    store.close()
