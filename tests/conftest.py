"""Shared fixtures: the Mitsuba backend, and an isolated data folder per test."""

from __future__ import annotations

import pytest

pytest_plugins = ["tests.fast_subset"]


@pytest.fixture(scope="session")
def mi():
    from renderers.backend import init_backend

    return init_backend()


@pytest.fixture
def data_dir(tmp_path, monkeypatch):
    """A fresh data folder (database, references, artifacts) for one test."""
    path = tmp_path / "data"
    monkeypatch.setenv("NIRC_BENCH_DATA_DIR", str(path))
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    return path
