"""Schemathesis against the OpenAPI schema: no generated request gets a 5xx.

Examples per operation are bounded (hypothesis settings) so the suite stays fast;
write endpoints are called with a valid API key so the generator reaches the
validation and storage code, not only the 401. Jobs are only queued (no
dispatcher): nothing renders.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from schemathesis.checks import not_a_server_error

from jobs.execution.apikeys import create_api_key
from service.api.main import create_app
from service.config import ServiceSettings
from tests.pg import postgres_database

_DATA = Path(tempfile.mkdtemp(prefix="nirc-fuzz-")) / "data"
# Queued jobs never finish here: no long poll may hold a generated request open.
APP = create_app(ServiceSettings(data_dir=_DATA, database_url=None, long_poll_max_s=0))
_, KEY = create_api_key(APP.state.store, "fuzz")
# Binary bodies (an uploaded EXR to compare against, a scene archive) are random bytes:
# none may make the service fail.
for _media_type in ("image/x-exr", "application/x-tar"):
    schemathesis.openapi.media_type(_media_type, st.binary(max_size=512))
schema = schemathesis.openapi.from_asgi("/openapi.json", APP)
FUZZ = settings(max_examples=30, deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


@schema.parametrize()
@FUZZ
def test_no_server_errors(case):
    case.call_and_validate(headers={"X-API-Key": KEY}, checks=[not_a_server_error])


@pytest.fixture(scope="module")
def pg_app():
    with postgres_database() as url:
        app = create_app(ServiceSettings(data_dir=_DATA.parent / "pg", database_url=url,
                                         long_poll_max_s=0))
        _, key = create_api_key(app.state.store, "fuzz")
        yield app, key
        app.state.store.close()


@schema.parametrize()
@FUZZ
def test_no_server_errors_on_postgresql(case, pg_app):
    app, key = pg_app
    case.call_and_validate(headers={"X-API-Key": key}, checks=[not_a_server_error], app=app)
