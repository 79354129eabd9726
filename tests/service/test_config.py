"""Each setting has one source: the store's settings hold what the store and the jobs
read, the service's configuration adds the HTTP front's and the scheduler's, and the
scenes' size limit is one, read when it is used."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from jobs.record.config import Settings
from renderers.scenes.vetting import scene_limits
from service.config import ServiceSettings

SERVICE_ONLY = {"public_read", "session_max_age_s", "max_body_bytes", "long_poll_max_s",
                "long_poll_max_waiters", "tls_ca_file", "tls_cert", "tls_key",
                "allow_plaintext_scheduler"}


def test_the_http_settings_are_the_service_s_own():
    assert not SERVICE_ONLY & set(Settings.model_fields)
    assert SERVICE_ONLY <= set(ServiceSettings.model_fields)
    assert set(Settings.model_fields) <= set(ServiceSettings.model_fields)


def test_the_environment_variables_keep_their_names(monkeypatch, tmp_path):
    monkeypatch.setenv("NIRC_BENCH_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("NIRC_BENCH_PUBLIC_READ", "false")
    monkeypatch.setenv("NIRC_BENCH_LONG_POLL_MAX_S", "7")
    monkeypatch.setenv("NIRC_BENCH_MAX_BODY_BYTES", "4096")
    monkeypatch.setenv("NIRC_BENCH_TLS_CA_FILE", str(tmp_path / "ca.pem"))
    settings = ServiceSettings()
    assert settings.data_dir == tmp_path and settings.public_read is False
    assert settings.long_poll_max_s == 7 and settings.max_body_bytes == 4096
    assert settings.scheduler_tls is not None
    assert settings.scheduler_tls.ca_file == tmp_path / "ca.pem"


def test_a_store_s_settings_keep_their_values_as_the_service_s(monkeypatch, tmp_path):
    monkeypatch.setenv("NIRC_BENCH_PUBLIC_READ", "true")
    store = Settings(data_dir=tmp_path / "data", max_job_work=5)
    service = ServiceSettings.of(store)
    assert service.data_dir == store.data_dir and service.max_job_work == 5
    assert service.database_url == store.database_url and service.public_read is True
    assert ServiceSettings.of(service) is service
    assert ServiceSettings(data_dir=tmp_path).scheduler_tls is None


def test_the_scene_size_limit_is_read_when_used(monkeypatch):
    monkeypatch.delenv("NIRC_BENCH_SCENE_MAX_FILE_BYTES", raising=False)
    monkeypatch.delenv("NIRC_BENCH_SCENE_MAX_BYTES", raising=False)
    assert (scene_limits().max_file_bytes, scene_limits().max_total_bytes) == (64 << 20, 256 << 20)
    monkeypatch.setenv("NIRC_BENCH_SCENE_MAX_FILE_BYTES", "123")
    monkeypatch.setenv("NIRC_BENCH_SCENE_MAX_BYTES", "456")
    assert (scene_limits().max_file_bytes, scene_limits().max_total_bytes) == (123, 456)
    monkeypatch.setenv("NIRC_BENCH_SCENE_MAX_BYTES", "lots")
    with pytest.raises(ValueError, match="NIRC_BENCH_SCENE_MAX_BYTES"):
        scene_limits()


def test_no_module_reads_a_scene_size_from_the_environment_but_the_one():
    """The scene size limits (NIRC_BENCH_SCENE_MAX_*) are named in one module; the number
    of uploads vetted at once (NIRC_BENCH_MAX_SCENE_PARSES) is no size."""
    root = Path(__file__).resolve().parents[2]
    readers = sorted(str(path.relative_to(root)) for package in ("renderers", "jobs", "service")
                     for path in (root / package).rglob("*.py")
                     if re.search(r"SCENE_MAX|MAX_SCENE(?!_PARSES)", path.read_text()))
    assert readers == ["renderers/scenes/vetting.py"]
