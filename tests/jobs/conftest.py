"""Fixtures for the job-store tests: a migrated SQLite store in a temporary folder."""

from collections.abc import Iterator
from pathlib import Path

import pytest

from jobs.config import Settings
from jobs.db import open_store
from jobs.store import Store


@pytest.fixture
def settings(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Settings:
    # A database URL in the developer's environment must not redirect the tests.
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    return Settings(data_dir=tmp_path / "data")


@pytest.fixture
def store(settings: Settings) -> Iterator[Store]:
    store = open_store(settings)
    yield store
    store.close()
