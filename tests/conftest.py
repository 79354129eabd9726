"""Shared fixtures: the Mitsuba backend, and an isolated data folder per test.

A test's data folder starts with a copy of a SQLite database that ``open_store``
migrated to the newest schema once per session (migrating a fresh one took 0.1 s of
CPU and 0.4 s on the loaded machine; tests/pg.py does the same for PostgreSQL). The
tests of migrating are marked ``empty_database`` and start without one.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

pytest_plugins = ["tests.fast_subset"]


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "empty_database: the test's database starts empty, not as a copy of "
                   "a migrated one (tests/conftest.py, tests/pg.py)")


@pytest.fixture(autouse=True)
def _no_job_scene_outlives_its_test():
    """A job run in this process keeps its scene for the next job's collection
    (jobs.protocol.executor.JobCollector): let go of it when the test ends, so that no
    later test's renders trace that scene's objects too (slower, and other kernels)."""
    yield
    executor = sys.modules.get("jobs.protocol.executor")
    if executor is not None:
        executor.COLLECTOR.release()


@pytest.fixture(scope="session")
def mi():
    from renderers.backend import init_backend

    return init_backend()


@pytest.fixture(scope="session")
def migrated_sqlite(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A SQLite database file migrated by ``open_store``, once per session."""
    from jobs.record.config import DATABASE_FILENAME, Settings
    from jobs.record.db import open_store

    folder = tmp_path_factory.mktemp("migrated")
    path = folder / DATABASE_FILENAME
    open_store(Settings(data_dir=folder, database_url=f"sqlite:///{path}")).close()
    return path


@pytest.fixture
def data_folder(request: pytest.FixtureRequest, tmp_path: Path) -> Path:
    """``tmp_path / 'data'``, holding a copy of the migrated SQLite database unless the
    test is marked ``empty_database``."""
    folder = tmp_path / "data"
    if request.node.get_closest_marker("empty_database") is None:
        migrated = request.getfixturevalue("migrated_sqlite")
        folder.mkdir()
        shutil.copy(migrated, folder / migrated.name)    # its mode too (0600)
    return folder


@pytest.fixture
def data_dir(data_folder, monkeypatch):
    """A fresh data folder (database, references, artifacts) for one test."""
    monkeypatch.setenv("NIRC_BENCH_DATA_DIR", str(data_folder))
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    return data_folder
