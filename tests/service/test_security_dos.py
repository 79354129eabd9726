"""Denial of service, each attack replayed: long polls that starved the thread pool
(against a real `nirc-bench serve` on loopback), bodies of any size, free-form
``params`` of any size or depth, and 422 answers that echoed all of it (in-process)."""

from __future__ import annotations

import asyncio
import json
import time
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest
from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key, verify_api_key
from jobs.execution.queue import JobQueue
from jobs.record.config import Settings
from jobs.record.db import open_store
from service.api.main import create_app
from tests.service.live import Service

SPEC = {"scene": "cornell-box", "method": "pt", "resolution": 8, "spp": 1, "frames": 1,
        "seeds": 1, "reference": {"spp": 64, "spp_per_pass": 8}}
#: Small enough for any echo of the offending input to be a cut one.
SMALL_ANSWER = 2000
POLLS = 50
#: service/api/limits.py's limits, spelled out so that this module also runs against a
#: service without them (and fails there).
MAX_STRING_CHARS = 4096
MAX_PARAMS_BYTES = 16_384


@pytest.fixture
def api(tmp_path, monkeypatch):
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    settings = Settings(data_dir=tmp_path / "data")
    store = open_store(settings)
    _, key = create_api_key(store, "tests")
    with TestClient(create_app(settings)) as client:
        client.headers["X-API-Key"] = key
        yield client
    store.close()


def _queued_jobs(data_dir, count: int, key: str) -> list[int]:
    """Jobs of ``key`` that the service does not dispatch (written behind its back, and
    its periodic re-dispatch is switched off): they stay queued."""
    store = open_store(Settings(data_dir=data_dir))
    try:
        queue, owner = JobQueue(store), verify_api_key(store, key)
        return [queue.submit("render", {**SPEC, "eps": 0.01 * (i + 1)}, f"idle-{i}",
                             owner_key_id=owner.id)[0].id
                for i in range(count)]
    finally:
        store.close()


def test_50_long_polls_do_not_delay_an_authenticated_post(tmp_path, monkeypatch):
    """Before: 45 unauthenticated `?wait_s=60` polls held every thread of the pool; an
    authenticated POST then waited for them (28 s). After: polls hold no thread, the
    POST answers at once, and polls beyond the service's limit are answered 429."""
    monkeypatch.setenv("NIRC_BENCH_LONG_POLL_MAX_WAITERS", str(POLLS))
    monkeypatch.setenv("NIRC_BENCH_REDISPATCH_INTERVAL_S", "3600")
    data_dir = tmp_path / "data"
    service = Service(data_dir)
    service.start()
    try:
        polled, canceled = _queued_jobs(data_dir, 2, service.key)

        async def attack() -> tuple[float, int]:
            limits = httpx.Limits(max_connections=POLLS + 10)
            async with httpx.AsyncClient(base_url=service.url, limits=limits,
                                         timeout=90) as client:
                polls = [asyncio.create_task(client.get(f"/api/v1/jobs/{polled}?wait_s=60"))
                         for _ in range(POLLS)]
                await asyncio.sleep(2.0)        # every poll is in and waiting
                assert not any(poll.done() for poll in polls), "a poll answered early"
                try:
                    extra = (await client.get(f"/api/v1/jobs/{polled}?wait_s=60",
                                              timeout=5)).status_code
                except httpx.TimeoutException:
                    extra = None
                start = time.monotonic()
                try:
                    answer = await client.post(f"/api/v1/jobs/{canceled}/cancel",
                                               headers={"X-API-Key": service.key}, timeout=10)
                except httpx.TimeoutException:
                    pytest.fail("the authenticated POST did not answer within 10 s")
                elapsed = time.monotonic() - start
                assert answer.status_code == 200, answer.text
                for poll in polls:
                    poll.cancel()
                await asyncio.gather(*polls, return_exceptions=True)
                return elapsed, extra

        # A thread of its own: a browser test earlier in the session may have left an
        # event loop running in this one (asyncio.run refuses to nest).
        with ThreadPoolExecutor(1) as pool:
            elapsed, extra_status = pool.submit(asyncio.run, attack()).result()
        assert elapsed < 2.0, f"the POST took {elapsed:.1f} s behind {POLLS} long polls"
        assert extra_status == 429
    finally:
        service.stop()


def test_a_5mb_body_is_refused_413_without_echo(tmp_path):
    """Before: a 5 MB spec was read whole and its 422 echoed all 5 MB. After: 413 naming
    the limit, decided from Content-Length before the body is read."""
    service = Service(tmp_path / "data")
    service.start()
    try:
        body = json.dumps({**SPEC, "scene": "x" * 5_000_000}).encode()
        answer = httpx.post(f"{service.url}/api/v1/jobs", content=body, timeout=30,
                            headers={"X-API-Key": service.key,
                                     "Content-Type": "application/json"})
        assert answer.status_code == 413, answer.text[:300]
        assert len(answer.content) < SMALL_ANSWER
        assert "1000000 bytes" in answer.json()["detail"]
    finally:
        service.stop()


def test_a_body_without_content_length_is_counted_as_it_streams(api):
    """A chunked body declares no size: it is refused once it passes the limit."""
    def chunks():
        yield b'{"scene": "'
        for _ in range(50):
            yield b"x" * 100_000
        yield b'"}'

    answer = api.post("/api/v1/jobs", content=chunks(),
                      headers={"Content-Type": "application/json"})
    assert answer.status_code == 413
    assert len(answer.content) < SMALL_ANSWER


def test_a_200kb_string_in_params_is_refused_with_a_cut_echo(api):
    """Before: 200 kB inside params.cache was stored (202) and served to every reader;
    200 kB in a pt parameter came back whole in the 422. After: 422 naming the field,
    with the echo cut."""
    big = "x" * 200_000
    for method, params, where in (("nirc", {"cache": {"note": big}}, ["params", "cache"]),
                                  ("pt", {"note": big}, ["params"])):
        answer = api.post("/api/v1/jobs", json={**SPEC, "method": method, "params": params})
        assert answer.status_code == 422, answer.text[:300]
        assert len(answer.content) < SMALL_ANSWER, len(answer.content)
        error = answer.json()["detail"][0]
        assert error["loc"] == ["body", *where, "note"]
        assert f"at most {MAX_STRING_CHARS}" in error["msg"]
        assert "200000 characters" in error["input"]
    assert api.get("/api/v1/jobs").json() == []      # nothing stored


def test_params_are_bounded_in_depth_and_total_size(api):
    nested: dict = {"leaf": 1}
    for _ in range(40):
        nested = {"inner": nested}
    answer = api.post("/api/v1/jobs", json={**SPEC, "method": "nirc", "params": {"cache": nested}})
    assert answer.status_code == 422 and "nested deeper" in answer.text
    assert len(answer.content) < SMALL_ANSWER
    wide = {f"k{i}": "y" * 1000 for i in range(MAX_PARAMS_BYTES // 1000 + 5)}
    answer = api.post("/api/v1/jobs", json={**SPEC, "method": "nirc", "params": {"cache": wide}})
    assert answer.status_code == 422, answer.text[:300]
    assert answer.json()["detail"][0]["loc"] == ["body", "params"]
    assert len(answer.content) < SMALL_ANSWER
    answer = api.post("/api/v1/sweeps", json={"scene": "cornell-box", "eps": [0.5] * 5000})
    assert answer.status_code == 422 and "at most 1000" in answer.text
    assert len(answer.content) < SMALL_ANSWER


def test_a_validation_error_repeats_a_cut_input(api):
    """A value under the string limit that fails validation comes back cut, not whole."""
    answer = api.post("/api/v1/jobs", json={**SPEC, "resolution": "9" * 3000 + "x"})
    assert answer.status_code == 422
    assert len(answer.content) < SMALL_ANSWER
    error = answer.json()["detail"][0]
    assert error["loc"] == ["body", "resolution"] and "3001 characters" in error["input"]
