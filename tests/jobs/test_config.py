"""Settings come from NIRC_BENCH_* environment variables, with an embedded default."""

from pathlib import Path

import pytest

from jobs.record.config import get_settings
from jobs.record.db import open_store


@pytest.fixture(autouse=True)
def _clean_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("NIRC_BENCH_DATA_DIR", raising=False)
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)


def test_default_is_data_folder_in_working_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    settings = get_settings()
    assert settings.data_dir == tmp_path / "data"
    assert settings.database_url == f"sqlite:///{tmp_path / 'data' / 'nirc-bench.db'}"
    assert settings.artifacts_dir == tmp_path / "data" / "artifacts"
    assert settings.references_dir == tmp_path / "data" / "references"


def test_data_dir_from_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NIRC_BENCH_DATA_DIR", str(tmp_path / "elsewhere"))
    settings = get_settings()
    assert settings.data_dir == tmp_path / "elsewhere"
    assert settings.database_url == f"sqlite:///{tmp_path / 'elsewhere' / 'nirc-bench.db'}"
    assert settings.artifacts_dir == tmp_path / "elsewhere" / "artifacts"


def test_relative_data_dir_is_made_absolute(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("NIRC_BENCH_DATA_DIR", "rel/data")
    assert get_settings().data_dir == tmp_path / "rel" / "data"


def test_database_url_from_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    url = f"sqlite:///{tmp_path / 'custom' / 'other.db'}"
    monkeypatch.setenv("NIRC_BENCH_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setenv("NIRC_BENCH_DATABASE_URL", url)
    settings = get_settings()
    assert settings.database_url == url
    assert settings.data_dir == tmp_path / "data"  # artifacts stay in the data folder


def test_get_settings_sees_environment_changes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("NIRC_BENCH_DATA_DIR", str(tmp_path / "a"))
    assert get_settings().data_dir == tmp_path / "a"
    monkeypatch.setenv("NIRC_BENCH_DATA_DIR", str(tmp_path / "b"))
    assert get_settings().data_dir == tmp_path / "b"


def test_open_store_uses_env_settings(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NIRC_BENCH_DATA_DIR", str(tmp_path / "nested" / "data"))
    store = open_store()
    try:
        assert (tmp_path / "nested" / "data" / "nirc-bench.db").is_file()
        assert store.list_runs() == []
    finally:
        store.close()
