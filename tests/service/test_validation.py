"""Every value of a submission is checked before it is queued: NaN and Infinity, strings
and booleans where numbers belong, in the spec and in the method's parameters, and
cache overrides the method's preset cannot build, are 422 naming the field (never a
500, never a job that fails when it runs)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key
from jobs.record.config import Settings
from jobs.record.db import open_store
from service.api.main import create_app

RENDER = {"scene": "cornell-box", "method": "pt", "resolution": 8, "spp": 1, "frames": 2,
          "seeds": 2, "reference": {"spp": 64, "spp_per_pass": 8}}
SWEEP = {"scene": "cornell-box", "eps": [0.5], "seeds": 2}


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    """The app in-process, no dispatcher (nothing runs), SQLite."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("data"), database_url=None)
    store = open_store(settings)
    _, key = create_api_key(store, "tests")
    with TestClient(create_app(settings, None)) as client:
        client.headers["X-API-Key"] = key
        yield client
    store.close()


def _post(client: TestClient, path: str, body: dict):
    """POST ``body`` as JSON text as a client may send it: NaN and Infinity included
    (Python's encoder writes them; a strict JSON client could not)."""
    return client.post(path, content=json.dumps(body),
                       headers={"Content-Type": "application/json"})


NAN, INF = float("nan"), float("inf")

NON_FINITE = [
    ("/api/v1/jobs", {"eps": NAN}, "eps"),
    ("/api/v1/jobs", {"resolution": NAN}, "resolution"),
    ("/api/v1/jobs", {"reference": {"spp": 64, "rel_stderr": INF}}, "rel_stderr"),
    ("/api/v1/jobs", {"time_budget": {"ms": INF}}, "ms"),
    ("/api/v1/jobs", {"params": {"rr_survival": NAN}}, "rr_survival"),
    ("/api/v1/jobs", {"method": "nirc", "params": {"cache": {"optimizer": {"lr": INF}}}},
     "params.cache.optimizer.lr"),
    ("/api/v1/sweeps", {"eps": [NAN]}, "eps"),
    ("/api/v1/sweeps", {"time_tolerance_ms": -INF}, "time_tolerance_ms"),
    ("/api/v1/sweeps", {"params": {"sph_c": NAN}}, "params.sph_c"),
]


@pytest.mark.parametrize("path, change, field", NON_FINITE)
def test_nan_and_infinity_are_422_naming_the_field(client, path, change, field):
    base = RENDER if path.endswith("jobs") else SWEEP
    response = _post(client, path, {**base, **change})
    assert response.status_code == 422, response.text
    detail = json.dumps(response.json()["detail"])
    # A float field says "finite number"; an integer field "valid integer" (of "NaN").
    assert field in detail and ("finite" in detail or "valid integer" in detail), detail


@pytest.mark.parametrize("path, field", [
    ("/api/v1/jobs/1?wait_s=nan", "wait_s"),
    ("/api/v1/ci/history?metric=mrse&scene=cornell-box&method=pt&alpha=nan", "alpha"),
])
def test_a_nan_query_number_is_422_saying_it_is_not_a_finite_number(client, path, field):
    """A range check alone read NaN as above the maximum ('less than or equal to 60')."""
    response = client.get(path)
    assert response.status_code == 422, response.text
    (error,) = response.json()["detail"]
    assert error["loc"] == ["query", field] and error["msg"] == "Input should be a finite number"


NOT_A_NUMBER = [
    ("/api/v1/jobs", {"resolution": "16"}, "resolution"),
    ("/api/v1/jobs", {"spp": True}, "spp"),
    ("/api/v1/jobs", {"eps": "0.1"}, "eps"),
    ("/api/v1/jobs", {"reference": {"spp": "64"}}, "spp"),
    ("/api/v1/jobs", {"keep_frames": 1}, "keep_frames"),
    ("/api/v1/jobs", {"params": {"max_depth": "4"}}, "max_depth"),
    ("/api/v1/jobs", {"params": {"rr_depth": True}}, "rr_depth"),
    ("/api/v1/jobs", {"method": "nirc", "params": {"nc": ["4"]}}, "nc"),
    ("/api/v1/sweeps", {"seeds": "3"}, "seeds"),
    ("/api/v1/sweeps", {"nc": [True]}, "nc"),
    ("/api/v1/sweeps", {"params": {"rr_depth": "2"}}, "rr_depth"),
]


BAD_CACHE = [
    ("/api/v1/jobs", {"method": "nirc", "params": {"cache": {"mlp": {"widht": 64}}}},
     "widht"),
    ("/api/v1/jobs", {"method": "nrc", "params": {"cache": {"bogus": 1}}}, "bogus"),
    ("/api/v1/jobs", {"method": "nvc-lights", "params": {"cache": {"preset": "huge"}}},
     "huge"),
    ("/api/v1/jobs", {"scene": "sky", "method": "nirc-nvc-env",
                      "params": {"env_cache": {"batch_size": 0}}}, "env_cache"),
    ("/api/v1/sweeps", {"params": {"cache": {"loss": {"kind": "l3"}}}}, "loss.kind"),
]


@pytest.mark.parametrize("path, change, field", NOT_A_NUMBER + BAD_CACHE)
def test_values_of_the_wrong_kind_are_422_naming_the_field(client, path, change, field):
    """Strings and booleans where numbers belong; cache overrides the method's preset
    cannot build (refused at submission, not by the job when it runs)."""
    base = RENDER if path.endswith("jobs") else SWEEP
    response = _post(client, path, {**base, **change})
    assert response.status_code == 422, response.text
    assert field in json.dumps(response.json()["detail"])


def test_a_valid_submission_with_numbers_in_float_fields_is_accepted(client):
    """Strictness does not refuse an integer where a float belongs (JSON has one number)."""
    body = {**RENDER, "eps": 1, "params": {"rr_survival": 1}, "seeds": 3}
    assert _post(client, "/api/v1/jobs", body).status_code == 202



def test_every_422_is_built_in_one_place():
    """Routes raise service.api.unprocessable's error; only that module writes a 422
    answer, so every refusal has the one shape ``{"detail": [{"loc", "msg", "type"}]}``."""
    service = Path(__file__).resolve().parents[2] / "service"
    writers = sorted(str(path.relative_to(service)) for path in service.rglob("*.py")
                     if "HTTP_422" in path.read_text() or "status_code=422" in path.read_text())
    assert writers == ["api/unprocessable.py"]


def test_an_nc_sweep_of_old_clients_is_a_parameter_sweep_with_its_termination(client):
    """A top-level termination: an N_c sweep's is NIRC's parameter; on an eps sweep a
    policy other than the default is refused, naming where a method's policy goes."""
    answer = _post(client, "/api/v1/sweeps", {"scene": "cornell-box", "nc": [2, 1],
                                              "termination": "sph", "seeds": 2})
    assert answer.status_code == 202, answer.text
    spec = answer.json()["spec"]
    assert spec["parameter"] == {"name": "nc", "values": [1, 2]} and spec["methods"] == ["nirc"]
    assert spec["params"] == {"termination": "sph"} and "termination" not in spec
    refused = _post(client, "/api/v1/sweeps", {**SWEEP, "termination": "sph"})
    assert refused.status_code == 422 and "params.termination" in refused.text
