"""Retention on its own, on SQLite and PostgreSQL: the service applies gc's retention
on a timer; an old unnamed run loses its artifacts (and its uploaded image, whose run
folder goes too), while a named run, a tagged run and a young run keep theirs, and the
log says what was removed. Before: nothing ran gc but an operator, it removed named
runs' images like any other, and it left the emptied run folders behind. Switched
off, nothing is removed (the control)."""

from __future__ import annotations

import logging
import time
from datetime import UTC, datetime, timedelta

import pytest
from fastapi.testclient import TestClient

from jobs.record.artifacts import ArtifactStore
from jobs.record.config import Settings
from jobs.record.db import open_store
from service.api.main import create_app
from tests.jobs.factories import artifact_fields, run_fields

#: Half a second between rounds.
INTERVAL_H = 0.5 / 3600


def _runs(store, settings: Settings) -> dict[str, int]:
    """Runs of 60 days (unnamed, named, tagged) and of 1 day, each with an image; an
    uploaded image under the old unnamed run."""
    artifacts = ArtifactStore(settings.artifacts_dir)
    ids = {}
    for name, days in (("old", 60), ("named", 60), ("tagged", 60), ("young", 1)):
        blob = artifacts.put_bytes(name.encode() * 50, ".exr")
        ids[name] = store.add_run(
            run_fields(created_at=datetime.now(UTC) - timedelta(days=days)), [],
            [{**artifact_fields("image", blob.sha256), "path": blob.relpath}]).id
    store.label_run(ids["named"], name="paper figure 3")
    store.label_run(ids["tagged"], set_tags={"keep": "yes"})
    image = settings.uploaded_images_dir / "1" / str(ids["old"]) / f"{'0' * 64}.exr"
    image.parent.mkdir(parents=True)
    image.write_bytes(b"exr")
    return ids


@pytest.mark.parametrize("interval_h", [INTERVAL_H, None])
def test_the_service_applies_retention_on_its_own(tmp_path, monkeypatch, caplog,
                                                  database_url, interval_h):
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    settings = Settings(data_dir=tmp_path / "data", database_url=database_url,
                        artifact_keep_days=30, retention_interval_h=interval_h)
    store = open_store(settings)
    ids = _runs(store, settings)
    caplog.set_level(logging.INFO, logger="uvicorn.error.retention")

    def kept() -> set[str]:
        return {name for name, run_id in ids.items() if store.get_run(run_id).artifacts}

    with TestClient(create_app(settings, None)):
        deadline = time.monotonic() + (10 if interval_h else 1.5)
        while "old" in kept() and time.monotonic() < deadline:
            time.sleep(0.1)
    run_folder = settings.uploaded_images_dir / "1" / str(ids["old"])
    if interval_h is None:
        assert kept() == set(ids) and run_folder.is_dir()
        assert not caplog.records
    else:
        assert kept() == {"named", "tagged", "young"}
        assert not run_folder.exists() and not run_folder.parent.exists()
        assert f"retention removed run artifacts run {ids['old']}" in caplog.text
    store.close()
