"""The REST API in-process: auth, validation (422 naming the field), idempotency, 404s,
and a job submitted over REST run to completion by a (thread) dispatcher."""

from __future__ import annotations

import threading
import time
from contextlib import ExitStack

import pytest
from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key, revoke_api_key
from jobs.execution.queue import JobQueue
from jobs.execution.runner import run_job
from jobs.record.config import Settings
from jobs.record.db import open_store
from service.api.main import create_app
from tests.pg import postgres_database

SPEC = {"scene": "cornell-box", "method": "pt", "resolution": 8, "spp": 1, "frames": 2,
        "seeds": 2, "reference": {"spp": 64, "spp_per_pass": 8}}


class ThreadDispatcher:
    """Runs each submitted job in a thread (the service uses Dask; same runner)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.threads: list[threading.Thread] = []

    def unavailable(self, device_class: str) -> None:
        return None

    def submit(self, job) -> None:
        thread = threading.Thread(target=run_job, args=(job.id, self.settings),
                                  kwargs={"worker": "thread"})
        thread.start()
        self.threads.append(thread)

    def recover(self, jobs=None) -> list[int]:
        return []       # nothing is stranded in these tests

    def recover_every(self, interval_s: float) -> threading.Event:
        return threading.Event()


@pytest.fixture(params=["sqlite", "postgresql"])
def api(request, tmp_path, monkeypatch):
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    with ExitStack() as stack:
        url = stack.enter_context(postgres_database()) if request.param == "postgresql" else None
        data = tmp_path / "data" if url else request.getfixturevalue("data_folder")
        yield from _api(Settings(data_dir=data, database_url=url))


def _api(settings: Settings):
    store = open_store(settings)
    _, key = create_api_key(store, "tests")
    dispatcher = ThreadDispatcher(settings)
    with TestClient(create_app(settings, dispatcher)) as client:
        client.headers["X-API-Key"] = key
        yield client, store, dispatcher, key
    for thread in dispatcher.threads:
        thread.join()
    store.close()


def _wait(client: TestClient, job_id: int, timeout: float = 300) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/api/v1/jobs/{job_id}").json()
        if job["status"] in ("succeeded", "failed", "canceled"):
            return job
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} did not finish: {job}")


def test_write_endpoints_need_a_valid_key(api):
    client, store, _, key = api
    assert client.post("/api/v1/jobs", json=SPEC, headers={"X-API-Key": ""}).status_code == 401
    wrong = key[:-4] + "AAAA"
    assert client.post("/api/v1/jobs", json=SPEC, headers={"X-API-Key": wrong}).status_code == 403
    assert client.post("/api/v1/jobs", json=SPEC, headers={"X-API-Key": "junk"}).status_code == 403
    revoke_api_key(store, key.split("_")[1])
    assert client.post("/api/v1/jobs", json=SPEC).status_code == 403
    assert client.get("/api/v1/jobs").status_code == 200   # reads stay open


@pytest.mark.parametrize("change, field", [
    ({"resolution": 0}, "resolution"),
    ({"scene": "no-such-scene"}, "scene"),
    ({"params": {"max_depth": 0}}, "params"),
    ({"method": "nope"}, "params"),
    ({"seeds": "many"}, "seeds"),
    ({"unknown_field": 1}, "unknown_field"),
    ({"method": "grid-cache", "params": {"termination": "mse-min",
                                         "termination_params": {"samples": -1}}}, "samples"),
])
def test_invalid_specs_are_422_naming_the_field(api, change, field):
    client = api[0]
    response = client.post("/api/v1/jobs", json={**SPEC, **change})
    assert response.status_code == 422, response.text
    assert field in str(response.json()["detail"])


def test_a_method_that_does_not_apply_is_refused_before_it_is_queued(api):
    """grid-cache on the glossy Cornell box: 422 naming why, from the scene's features,
    and no job queued (before: queued, and refused by its render after the reference)."""
    client = api[0]
    response = client.post("/api/v1/jobs", json={**SPEC, "scene": "cornell-glossy",
                                                 "method": "grid-cache"})
    assert response.status_code == 422, response.text
    detail = response.json()["detail"][0]
    assert detail["loc"] == ["body", "method"]
    assert "does not apply" in detail["msg"] and "glossy" in detail["msg"]
    assert client.get("/api/v1/jobs").json() == []


def test_a_grid_cache_job_runs_with_its_policy_and_states_its_roulette(api):
    """A variance-trading policy over REST: its parameters are stored with the run, the
    grid's typed configuration with the seeds, and the roulette's survival probability
    in the path statistics."""
    client = api[0]
    params = {"termination": "var-bound", "prefill_frames": 2, "rr_survival": 0.8,
              "termination_params": {"threshold": 0.5, "relative": True}}
    response = client.post("/api/v1/jobs", json={**SPEC, "method": "grid-cache",
                                                 "params": params})
    assert response.status_code == 202, response.text
    job = _wait(client, response.json()["id"])
    assert job["status"] == "succeeded", job
    run = client.get(f"/api/v1/runs/{job['run_id']}").json()
    assert run["params"]["termination_params"] == {"threshold": 0.5, "relative": True}
    assert run["path_stats"]["rr_survival"] == 0.8
    assert run["caches"]["cache"]["config"]["samples_per_vertex"] > 1
    # Labelled by what differs from grid-cache's defaults (var-bound is its default policy).
    assert run["method_label"].startswith("grid-cache (termination_params {")
    assert "threshold:0.5" in run["method_label"] and "rr_survival 0.8" in run["method_label"]


def test_unknown_ids_are_404(api):
    client = api[0]
    for path in ("/api/v1/jobs/999", "/api/v1/runs/999", "/api/v1/artifacts/999",
                 "/api/v1/sweeps/999", "/api/v1/compare?runs=998,999"):
        assert client.get(path).status_code == 404, path
    assert client.post("/api/v1/jobs/999/cancel").status_code == 404


def test_a_job_runs_and_its_results_are_served(api):
    client, _, _, _ = api
    response = client.post("/api/v1/jobs", json=SPEC, headers={"Idempotency-Key": "one"})
    assert response.status_code == 202
    assert response.headers["Location"] == f"/api/v1/jobs/{response.json()['id']}"
    job_id = response.json()["id"]
    again = client.post("/api/v1/jobs", json=SPEC,
                        headers={"Idempotency-Key": "one"})
    assert again.json()["id"] == job_id
    same_spec = client.post("/api/v1/jobs", json=SPEC)
    assert same_spec.json()["id"] == job_id

    job = _wait(client, job_id)
    assert job["status"] == "succeeded" and job["attempts"] == 1, job
    run = client.get(f"/api/v1/runs/{job['run_id']}").json()
    assert len(run["per_seed"]) == 2 and run["mrse"] > 0 and run["device"]["device_key"]
    # Registry metrics are served under their fields; PSNR (higher is better) among them.
    assert run["psnr"] == run["metrics"]["psnr_mean"] and run["flip"] == run["metrics"]["flip_hdr_mean"]
    registry = {m["name"]: m for m in client.get("/api/v1/metrics").json()}
    assert registry["psnr"]["direction"] == "higher" and registry["mrse"]["field"] == "mrse"
    assert run["timings"]["protocol"] and run["versions"]["mitsuba"]
    preview = client.get(f"/api/v1/references/{run['reference_id']}/preview.png")
    assert preview.status_code == 200 and preview.content[:4] == b"\x89PNG"
    image = next(a for a in run["artifacts"] if a["kind"] == "image")
    # One image per seed, each saying whose it is; the run's own files name none.
    assert sorted(a["seed"] for a in run["artifacts"] if a["kind"] == "image") == [0, 1]
    data = client.get(image["url"])
    assert data.status_code == 200 and data.content[:4] == b"\x76\x2f\x31\x01"  # EXR magic
    listed = client.get("/api/v1/results", params={"scene": "cornell-box"}).json()
    assert [r["id"] for r in listed] == [run["id"]]
    assert client.get("/api/v1/results", params={"method": "nrc"}).json() == []

    other = _wait(client, client.post("/api/v1/jobs", json={**SPEC, "spp": 2}).json()["id"])
    comparison = client.get("/api/v1/compare",
                            params={"runs": f"{run['id']},{other['run_id']}"}).json()
    assert comparison["same_device"] and len(comparison["runs"]) == 2


def test_scenes_and_openapi(api):
    client = api[0]
    names = {scene["name"] for scene in client.get("/api/v1/scenes").json()}
    assert "door" in names and "cornell-box" in names
    schema = client.get("/openapi.json").json()
    assert "/api/v1/jobs" in schema["paths"] and "/api/v1/sweeps" in schema["paths"]
    assert client.get("/docs").status_code == 200


def test_the_dashboard_is_served_without_external_assets(api):
    client = api[0]
    page = client.get("/")
    assert page.status_code == 200 and "text/html" in page.headers["content-type"]
    for asset in ("/static/app.js", "/static/charts.js", "/static/compare.js",
                  "/static/pixels.js", "/static/style.css",
                  "/static/vendor/img-comparison-slider/index.js",
                  "/static/vendor/img-comparison-slider/styles.css"):
        response = client.get(asset)
        assert response.status_code == 200, asset
        text = response.text.replace("http://www.w3.org/2000/svg", "")
        assert "http://" not in text and "https://" not in text, asset   # no CDN
    assert "https://" not in page.text and "http://" not in page.text
    # The chart library: served by the app (its code names URLs in strings, but the
    # browser tests check that no page requests anything from another origin).
    bundle = client.get("/vendor/vega.js")
    assert bundle.status_code == 200 and "javascript" in bundle.headers["content-type"]
    assert "window.vegaEmbed" in bundle.text
    assert client.get("/api/v1/sweeps").json() == []
    assert client.get("/api/v1/references/999/preview.png").status_code == 404


def test_a_long_poll_answers_as_soon_as_the_job_is_final(api):
    client, store, _, _ = api
    queue = JobQueue(store)
    job, _ = queue.submit("render", {**SPEC, "seeds": 3}, "long-poll")   # never dispatched
    started = time.monotonic()
    assert client.get(f"/api/v1/jobs/{job.id}?wait_s=0.5").json()["status"] == "queued"
    assert time.monotonic() - started >= 0.5
    canceler = threading.Timer(0.5, queue.cancel, args=(job.id,))
    canceler.start()
    started = time.monotonic()
    assert client.get(f"/api/v1/jobs/{job.id}?wait_s=30").json()["status"] == "canceled"
    assert time.monotonic() - started < 10          # not the 30 s it was allowed
    canceler.join()
    assert client.get(f"/api/v1/jobs/{job.id}?wait_s=61").status_code == 422
