"""A job's parameters are validated once, where it enters: a bad nested parameter (a
termination policy's own parameter, a cache-config override) is refused there — REST
422, CLI exit 2 with one line — and a job that got in reaches the executor as typed
objects, validated once more only where a process reads it from the queue."""

from __future__ import annotations

import sys
from types import SimpleNamespace
from typing import Any
from unittest import mock

import pytest
from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key
from jobs.execution.queue import JobQueue
from jobs.execution.queued import QueuedRender, job_of
from jobs.record.config import Settings
from jobs.record.db import open_store
from renderers.integrators.termination import POLICIES, params_model
from renderers.methods import get_method, parse_params
from service.api.main import create_app
from service.cli import main

BAD_NESTED = {
    "termination policy": ("grid-cache", {"termination": "var-bound",
                                          "termination_params": {"threshold": -1.0}},
                           "threshold"),
    "cache override": ("nirc", {"cache": {"no_such_field": 1}}, "no_such_field"),
}
GOOD = {"scene": "cornell-box", "method": "grid-cache", "resolution": 8, "seeds": 2,
        "params": {"termination": "var-bound", "termination_params": {"threshold": 0.5}}}


class _Counting:
    """A model's validator that counts its validations (model_validate and __init__
    both go through ``validate_python``)."""

    def __init__(self, inner: Any) -> None:
        self.inner, self.calls = inner, 0

    def validate_python(self, *args: Any, **kwargs: Any) -> Any:
        self.calls += 1
        return self.inner.validate_python(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


@pytest.fixture
def validations(monkeypatch):
    """method -> the counter of its parameter model's validations."""
    def spy(method: str) -> _Counting:
        model = get_method(method).params
        counter = _Counting(model.__pydantic_validator__)
        monkeypatch.setattr(model, "__pydantic_validator__", counter)
        return counter
    return spy


@pytest.fixture
def policy_validations(monkeypatch):
    """The counters of every registered policy's parameter models (its own ``Params``
    and the tagged model the methods hold), by model."""
    counters = {}
    for cls in POLICIES.values():
        for model in {cls.Params, params_model(cls)}:
            counters[model] = _Counting(model.__pydantic_validator__)
            monkeypatch.setattr(model, "__pydantic_validator__", counters[model])
    return counters


@pytest.fixture
def api(tmp_path, monkeypatch):
    """The app without a dispatcher (jobs stay queued) and its queue."""
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    settings = Settings(data_dir=tmp_path / "data")
    store = open_store(settings)
    _, key = create_api_key(store, "tests")
    client = TestClient(create_app(settings, None))
    client.headers["X-API-Key"] = key
    yield client, JobQueue(store), store, settings
    store.close()


@pytest.mark.parametrize("case", BAD_NESTED)
def test_a_bad_nested_parameter_is_a_422_at_submission(api, validations, case):
    client, queue, _, _ = api
    method, params, field = BAD_NESTED[case]
    counter = validations(method)
    response = client.post("/api/v1/jobs", json={**GOOD, "method": method, "params": params})
    assert response.status_code == 422, response.text
    assert field in response.text and f"invalid {method} parameters" in response.text
    assert counter.calls == 1 and queue.list() == []


@pytest.mark.parametrize("case", BAD_NESTED)
def test_a_bad_nested_parameter_is_one_line_and_exit_2_from_the_cli(
        tmp_path, capsys, validations, case):
    method, params, field = BAD_NESTED[case]
    counter = validations(method)
    options = [f"{name}={value}".replace("'", '"') for name, value in params.items()]
    argv = ["nirc-bench", "render", "--scene", "cornell-box", "-m", method, "--res", "8",
            *[arg for option in options for arg in ("-p", option)], "--data-dir", str(tmp_path)]
    with mock.patch.object(sys, "argv", argv), pytest.raises(SystemExit) as exit_info:
        main()
    text = capsys.readouterr().err
    assert exit_info.value.code == 2 and text.count("\n") == 1, text
    assert field in text and "Traceback" not in text
    assert counter.calls == 1     # refused before any render process started


def test_a_submitted_job_is_validated_once_here_and_once_where_it_is_run(
        api, validations, monkeypatch):
    """The route validates the parameters once; a runner reading the row parses it
    once (job_of) and hands the executor the typed job, validating nothing more. The
    spy sees every validation: reading the row is one more."""
    client, queue, store, settings = api
    counter = validations("grid-cache")
    response = client.post("/api/v1/jobs", json=GOOD)
    assert response.status_code == 202, response.text
    assert counter.calls == 1
    queued = job_of(queue.get(response.json()["id"]))
    assert isinstance(queued, QueuedRender) and counter.calls == 2
    executed: list[Any] = []
    monkeypatch.setattr("jobs.protocol.executor.execute",
                        lambda job, *_args, **_kwargs: executed.append(job) or
                        mock.Mock(run_id=1, reference={}, reused=False))
    queued.run(store, settings, None, job_id=response.json()["id"])
    assert executed == [queued.job] and counter.calls == 2
    assert executed[0].params is queued.job.params
    assert executed[0].params.termination_params.threshold == 0.5


def test_the_policy_is_built_from_the_parsed_parameters_without_validating_them(
        policy_validations):
    """The method's parse validates the policy's parameters (nested in its own
    validation); building the policy hands them over as they are. The spies see a
    policy model validated on its own: as make_policy did before, the last call."""
    params = parse_params("grid-cache", GOOD["params"])
    policy = params.termination_policy()
    assert policy.params is params.termination_params and policy.params.threshold == 0.5
    assert sum(counter.calls for counter in policy_validations.values()) == 0
    type(policy).Params.model_validate({"threshold": 0.5})     # the validation it no longer does
    assert sum(counter.calls for counter in policy_validations.values()) == 1


def test_the_cache_is_made_from_the_parsed_config_without_validating_it(monkeypatch):
    """Parsing builds the cache's config from its preset and overrides once; the frame's
    training budget and make_cache take that object. The spy sees a config validated on
    its own: as make_cache did before (the preset called with the overrides), at the
    end."""
    from renderers.caches.config import CacheConfig, nirc_config
    from renderers.methods.cached import make_cache

    params = parse_params("nirc", {"cache": {"batch_size": 256}})
    counter = _Counting(CacheConfig.__pydantic_validator__)
    monkeypatch.setattr(CacheConfig, "__pydantic_validator__", counter)
    made: list[Any] = []
    monkeypatch.setattr("renderers.caches.NeuralCache",
                        lambda config, *_args, **_kwargs: made.append(config))
    box = SimpleNamespace(min=[0.0] * 3, max=[1.0] * 3)
    get_method("nirc").stage_sizes(params, 64, 1)
    make_cache(SimpleNamespace(scene=SimpleNamespace(bbox=lambda: box)),
               params.cache_config(), seed=0)
    assert made == [params.cache_config()] and made[0].batch_size == 256
    assert counter.calls == 0
    nirc_config(**params.cache)     # the validation it no longer does
    assert counter.calls > 0


def test_a_cancel_answer_says_the_cancel_was_requested_as_a_read_after_it_does(api):
    """A queued job is canceled at once; a running one is 'canceling' (the answer said
    'running', as if the cancel had not been heard) in the answer and in every read until
    its runner has stopped it, then 'canceled'."""
    client, queue, _, _ = api
    running, queued = (client.post("/api/v1/jobs", json={**GOOD, "seeds": seeds}).json()["id"]
                       for seeds in (2, 3))
    assert queue.claim(running, "worker-1") is not None

    def status(job_id: int) -> str:
        return client.get(f"/api/v1/jobs/{job_id}").json()["status"]

    assert status(running) == "running"
    answer = client.post(f"/api/v1/jobs/{running}/cancel")
    assert answer.status_code == 200 and answer.json()["status"] == "canceling"
    assert status(running) == "canceling"
    assert [j["status"] for j in client.get("/api/v1/jobs").json() if j["id"] == running] \
        == ["canceling"]
    assert client.post(f"/api/v1/jobs/{queued}/cancel").json()["status"] == "canceled"
    assert status(queued) == "canceled"
    queue.fail(running, "canceled while running", retry=True)   # as its runner stops it
    assert status(running) == "canceled"
