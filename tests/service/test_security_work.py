"""Exactly once and bounded work over REST: concurrent replays make one job, a reused
Idempotency-Key is refused, oversized jobs and sweeps are refused with their estimate
and the limit, a full disk refuses new jobs, a FIFO in a scene cannot hang a worker,
a job without --job-timeout gets one from its size, and a canceled stage cancels
what depends on it."""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from types import SimpleNamespace

import pytest
from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key
from jobs.execution.queue import JobQueue
from jobs.record.config import Settings
from jobs.record.db import open_store
from service.api.main import create_app

SPEC = {"scene": "cornell-box", "method": "pt", "resolution": 16, "spp": 1, "frames": 2,
        "seeds": 2, "reference": {"spp": 64, "spp_per_pass": 8}}
SWEEP = {"scene": "cornell-box", "eps": [0.5], "seeds": 2, "resolution": 16}


@pytest.fixture
def api(tmp_path, monkeypatch):
    """The app without a dispatcher (jobs stay queued); settings changed per test."""
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)

    def make(**overrides):
        settings = Settings(data_dir=tmp_path / "data", **overrides)
        store = open_store(settings)
        _, key = create_api_key(store, "tests")
        client = TestClient(create_app(settings, None))
        client.headers["X-API-Key"] = key
        return client, JobQueue(store)

    return make


def test_concurrent_replays_of_one_request_make_one_job(api):
    client, queue = api()
    with ThreadPoolExecutor(20) as pool:
        answers = list(pool.map(lambda _: client.post("/api/v1/jobs", json=SPEC), range(20)))
    assert {a.status_code for a in answers} == {202}
    assert len({a.json()["id"] for a in answers}) == 1
    assert len(queue.list()) == 1


def test_an_idempotency_key_reused_for_another_request_is_422(api):
    client, queue = api()
    key = {"Idempotency-Key": "once"}
    first = client.post("/api/v1/jobs", json=SPEC, headers=key)
    assert first.status_code == 202
    assert client.post("/api/v1/jobs", json=SPEC, headers=key).json()["id"] == first.json()["id"]
    other_body = client.post("/api/v1/jobs", json={**SPEC, "seeds": 3}, headers=key)
    assert other_body.status_code == 422, other_body.text
    assert "Idempotency-Key" in str(other_body.json()["detail"])
    other_endpoint = client.post("/api/v1/sweeps", json=SWEEP, headers=key)
    assert other_endpoint.status_code == 422 and "was used for a render" in other_endpoint.text
    assert len(queue.list()) == 1


def test_a_sweep_with_too_many_stages_is_refused_at_once(api):
    client, queue = api()
    started = time.monotonic()
    response = client.post("/api/v1/sweeps", json={**SWEEP, "seeds": 1000})
    assert response.status_code == 422, response.text
    assert "2003 stage jobs" in response.text and "max_sweep_stages" in response.text
    assert time.monotonic() - started < 2 and queue.list() == []


def test_a_job_over_the_work_limit_is_refused_with_its_estimate(api):
    client, queue = api(max_job_work=100_000)
    # 64x64 x (64 reference spp + 1 spp x 2 frames x 8 seeds) = 327680 path samples.
    assert client.post("/api/v1/jobs", json=SPEC).status_code == 202
    big = client.post("/api/v1/jobs", json={**SPEC, "resolution": 64, "seeds": 8})
    assert big.status_code == 422, big.text
    message = big.json()["detail"][0]["msg"]
    assert "estimated at 3.28e+05 path samples" in message and "1e+05" in message, message
    assert "max_job_work" in message
    sweep = client.post("/api/v1/sweeps", json=SWEEP)          # 100 training frames per cache
    assert sweep.status_code == 422 and "caches" in sweep.text
    assert len(queue.list()) == 1


def test_pretraining_counts_in_the_time_estimate_and_is_refused_over_the_bound(api):
    """Before, 100 000 pre-training frames were estimated at 2 s and accepted."""
    client, queue = api(max_job_seconds=3600)
    nirc = {**SPEC, "method": "nirc", "seeds": 1}
    assert client.post("/api/v1/jobs", json=nirc).status_code == 202
    long = client.post("/api/v1/jobs", json={**nirc, "params": {"pretrain_frames": 100_000}})
    assert long.status_code == 422, long.text
    limits = long.json()["detail"][0]["ctx"]
    assert limits["estimated_s"] > limits["limit_s"] == 3600, limits
    assert len(queue.list()) == 1


def test_a_full_disk_refuses_new_jobs(api):
    client, queue = api(max_data_bytes=1000)
    response = client.post("/api/v1/jobs", json=SPEC)
    assert response.status_code == 507, response.text
    assert "max_data_bytes" in response.text and "nirc-bench gc" in response.text
    assert queue.list() == []


def test_a_job_without_a_timeout_gets_one_from_its_size(tmp_path, monkeypatch):
    from jobs.execution.runner import _timeout_of
    from jobs.execution.timecost import DEFAULT
    from jobs.execution.work import render_work
    from jobs.protocol.spec import RenderSpec

    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    settings = Settings(data_dir=tmp_path / "data", job_timeout_min_s=60,
                        timeout_samples_per_s=1000)
    store = open_store(settings)
    job = SimpleNamespace(kind="render", spec=SPEC, device_class="cpu")
    samples = render_work(RenderSpec(**SPEC)).samples
    assert samples == 16 * 16 * (64 + 2 * 2)
    assert _timeout_of(job, settings, None, store) == 60 + samples / 1000
    assert _timeout_of(job, settings, 5.0, store) == 5.0
    # A job whose samples are few but whose frames are many: twice its estimated time.
    many = {**SPEC, "frames": 10_000}
    frames = 10_000 * 2 + 64 // 8        # seeds x frames, and the reference's passes
    timeout = _timeout_of(SimpleNamespace(kind="render", spec=many, device_class="cpu"),
                          settings, None, store)
    assert timeout >= 60 + 2 * frames * DEFAULT.frame_s
    store.close()


def test_a_canceled_stage_cancels_what_needs_it(tmp_path, monkeypatch):
    from jobs.execution.graph import sweep_stages
    from jobs.execution.runner import run_job
    from jobs.protocol.spec import SweepSpec

    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    settings = Settings(data_dir=tmp_path / "data")
    queue = JobQueue(open_store(settings))
    spec = SweepSpec(**SWEEP)
    sweep, _ = queue.submit("sweep", spec.model_dump(mode="json"), "sweep")
    stages = queue.stage_jobs(sweep, sweep_stages(spec))
    queue.cancel(stages["reference"].id)
    cache = stages["nirc cache 1/2"]
    assert run_job(cache.id, settings, worker="w", upstream=("canceled",)) == "canceled"
    assert "stage 'reference' canceled" in queue.get(cache.id).error


def test_a_fifo_in_a_scene_is_refused_before_anything_opens_it(tmp_path, mi):
    from renderers.scenes import load_scene
    from renderers.scenes.errors import SceneError

    fifo = tmp_path / "mesh.ply"
    os.mkfifo(fifo)
    scene = tmp_path / "scene.xml"
    scene.write_text('<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm"/>'
                     '</sensor><shape type="ply"><string name="filename" value="mesh.ply"/>'
                     '</shape></scene>')
    outcome: list[BaseException | None] = []

    def load() -> None:
        try:
            load_scene(str(scene), 16)
            outcome.append(None)
        except BaseException as err:  # noqa: BLE001 - reported below
            outcome.append(err)

    thread = threading.Thread(target=load, daemon=True)
    thread.start()
    thread.join(20)
    if thread.is_alive():       # blocked opening the FIFO: unblock it, then fail
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        thread.join(20)
        pytest.fail("loading a scene that names a FIFO blocked")
    assert isinstance(outcome[0], SceneError) and "not a regular file" in str(outcome[0])


def test_scene_files_over_the_size_cap_are_refused(tmp_path, monkeypatch):
    from renderers.scenes import loader
    from renderers.scenes.errors import SceneError

    (tmp_path / "mesh.ply").write_bytes(b"p" * 100)
    scene = tmp_path / "scene.xml"
    scene.write_text('<scene version="3.0.0"><shape type="ply">'
                     '<string name="filename" value="mesh.ply"/></shape></scene>')
    monkeypatch.setenv("NIRC_BENCH_SCENE_MAX_FILE_BYTES", "99")      # the XML is 99 bytes
    with pytest.raises(SceneError, match="100 bytes, more than the 99"):
        loader.check_scene_files(scene)
    monkeypatch.setenv("NIRC_BENCH_SCENE_MAX_FILE_BYTES", "10")
    with pytest.raises(SceneError, match="scene file .* more than the 10"):
        loader.load_scene(str(scene), 16)
