"""Errors served over the API name the data folder's files relative to it
(``<data>/references/...``), not by the absolute path stored with them: a job's
error, its stages' errors, a sweep's result. The stored texts keep the whole path.
The errors here are real: what reading a damaged reference raises, stored as a
job's runner stores it. The data folder is reached through a symbolic link, so
both spellings of its path occur."""

from __future__ import annotations

import errno
import os
from collections.abc import Iterator
from datetime import UTC, datetime

import pytest
from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key
from jobs.execution.graph import Stage
from jobs.execution.queue import JobQueue
from jobs.record.db import open_store
from metrics.imageio import ImageReadError, read_exr
from service.api.main import create_app
from service.config import ServiceSettings


@pytest.fixture
def settings(tmp_path) -> ServiceSettings:
    (tmp_path / "real").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "real")
    return ServiceSettings(data_dir=tmp_path / "link" / "data", database_url=None)


@pytest.fixture
def api(settings) -> Iterator[TestClient]:
    _, key = create_api_key(open_store(settings), "tests")
    with TestClient(create_app(settings)) as client:
        client.headers["X-API-Key"] = key
        yield client


def _reading_error(path) -> str:
    """What the runner stores when reading the damaged file at ``path`` fails."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"not an EXR")
    with pytest.raises(ImageReadError) as raised:
        read_exr(path)
    return f"{raised.type.__name__}: {raised.value}"


def _failed(queue: JobQueue, job, error: str) -> None:
    queue.claim(job.id, "worker")
    queue.fail(job.id, error, retry=False)


def test_errors_name_the_data_folders_files_relative_to_it(settings, api):
    data = settings.data_dir
    error = _reading_error(settings.references_dir / "damaged.exr")
    resolved_error = _reading_error(settings.references_dir.resolve() / "stage.exr")
    assert str(data) in error and str(data.resolve()) in resolved_error
    queue = JobQueue(open_store(settings))
    sweep_job, _ = queue.submit("sweep", {"scene": "cornell-box"}, "sweep-key")
    stage = queue.stage_jobs(sweep_job, [Stage(name="reference", task={})])["reference"]
    _failed(queue, sweep_job, error)
    _failed(queue, stage, resolved_error)
    store = queue.store
    sweep = store.start_sweep(key="k", kind="eps", scene_name="cornell-box", spec={},
                              scene_fingerprint="f",
                              device_key="d", estimator_versions={}, metric_version=1)
    elsewhere = f"{data}-old/references/kept.exr"      # another folder: served as stored
    store.finish_sweep(sweep.id, status="failed", finished_at=datetime.now(UTC),
                       result={"error": error, "points": [{"reason": resolved_error}],
                               "note": elsewhere})

    job = api.get(f"/api/v1/jobs/{sweep_job.id}").json()
    assert job["error"] == error.replace(str(data), "<data>")
    assert "<data>/references/damaged.exr" in job["error"]
    assert job["stages"][0]["error"] == resolved_error.replace(str(data.resolve()), "<data>")
    listed = api.get("/api/v1/jobs").json()
    assert {j["error"] for j in listed} == {job["error"], job["stages"][0]["error"]}
    result = api.get(f"/api/v1/sweeps/{sweep.id}").json()["result"]
    assert result == {"error": job["error"], "points": [{"reason": job["stages"][0]["error"]}],
                      "note": elsewhere}
    assert api.get("/api/v1/sweeps?include_old=true").json()[0]["result"] == result
    for text in (api.get(f"/api/v1/jobs/{sweep_job.id}").text, api.get("/api/v1/jobs").text,
                 api.get(f"/api/v1/sweeps/{sweep.id}").text):
        assert str(data) not in text.replace(elsewhere, "")
        assert str(data.resolve()) not in text
    assert queue.get(sweep_job.id).error == error      # stored whole


def test_a_full_disk_names_the_file_relative_to_the_data_folder(settings, api):
    """A 507 (the handler of every route's storage failures) names the file it could
    not write as the job errors do."""
    target = settings.artifacts_dir / "run" / "image.exr"

    def write() -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(target))

    api.app.add_api_route("/api/v1/test-full-disk", write)
    response = api.get("/api/v1/test-full-disk")
    assert response.status_code == 507
    assert "(<data>/artifacts/run/image.exr)" in response.json()["detail"]
    assert str(settings.data_dir) not in response.text
