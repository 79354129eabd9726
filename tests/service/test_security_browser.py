"""What a web page in a browser on the service's machine can make of it: reading it
through a domain of its own that resolves to loopback (DNS rebinding: any Host header
was answered 200), and the headers that keep a browser from misusing an answer (a 500
had none; the API viewers had no Content-Security-Policy, checked in Chromium)."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest
from fastapi.testclient import TestClient
from playwright.sync_api import Error as PlaywrightError

from jobs.record.db import open_store
from service.api.main import create_app
from service.cli import decide_allowed_hosts
from service.config import ServiceSettings
from service.errors import UsageError
from tests.service.conftest import open_page, serve, wait_until


@pytest.fixture(scope="module")
def loopback_app(tmp_path_factory) -> Iterator[TestClient]:
    """The app as `serve --host 127.0.0.1` builds it (reads open on loopback)."""
    settings = ServiceSettings(data_dir=tmp_path_factory.mktemp("browser") / "data",
                               database_url=None, public_read=True,
                               allowed_hosts=decide_allowed_hosts(None, "127.0.0.1"))
    open_store(settings).close()
    with TestClient(create_app(settings)) as client:
        yield client


def test_a_rebinding_domain_cannot_read_the_service(loopback_app):
    for host in ("attacker.example", "attacker.example:8000", "127.0.0.1.attacker.example"):
        answer = loopback_app.get("/api/v1/jobs", headers={"Host": host})
        assert answer.status_code == 400, (host, answer.status_code)
        assert "x-content-type-options" in answer.headers     # still under the headers
    for host in ("localhost:8000", "127.0.0.1:8000", "[::1]:8000", "LOCALHOST"):
        assert loopback_app.get("/api/v1/jobs", headers={"Host": host}).status_code == 200, host


def test_serve_answers_to_loopback_and_its_address_unless_told_otherwise(monkeypatch):
    assert set(decide_allowed_hosts(None, "::1")) == {"localhost", "127.0.0.1", "::1"}
    assert "bench.lan" in decide_allowed_hosts(None, "bench.lan")
    assert decide_allowed_hosts(["bench.example"], "0.0.0.0") == ["bench.example"]
    for wildcard in ("0.0.0.0", "::", "[::]"):
        with pytest.raises(UsageError, match="--allowed-hosts"):
            decide_allowed_hosts(None, wildcard)
    monkeypatch.setenv("NIRC_BENCH_ALLOWED_HOSTS", "bench.example, ::1")
    assert ServiceSettings().allowed_hosts == ["bench.example", "::1"]


def test_an_internal_error_carries_the_security_headers(loopback_app):
    """Before: a 500 (written outside every middleware) had none of them."""
    app = loopback_app.app

    @app.get("/api/v1/fails-for-this-test", include_in_schema=False)
    def fails() -> None:
        raise RuntimeError("planted")

    with TestClient(app, raise_server_exceptions=False, base_url="http://localhost") as client:
        answer = client.get("/api/v1/fails-for-this-test")
    assert answer.status_code == 500 and answer.json()["detail"].startswith("internal error")
    assert answer.headers["x-content-type-options"] == "nosniff"
    assert answer.headers["x-frame-options"] == "DENY"
    assert "frame-ancestors 'none'" in answer.headers["content-security-policy"]


def test_the_api_viewers_run_under_a_policy_of_their_own(chromium, tmp_path):
    """Before: /docs and /redoc had no Content-Security-Policy. Their inline start
    script runs by its hash; a script injected into the page does not."""
    settings = ServiceSettings(data_dir=tmp_path / "data", database_url=None,
                               public_read=True)
    with serve(create_app(settings)) as url:
        for path, drawn in (("/docs", "document.querySelectorAll('.opblock').length > 3"),
                            ("/redoc", "document.querySelectorAll('h2').length > 3")):
            answer = httpx.get(url + path)
            policy = answer.headers["content-security-policy"]
            assert "script-src 'self'" in policy and "'unsafe-inline'" not in \
                policy.split("script-src")[1].split(";")[0], policy
            page, errors = open_page(chromium, url + path)
            wait_until(page, drawn)
            # ReDoc's search worker, built by its script from a blob of this origin.
            own_blob = f"request to another origin: blob:{url}/"
            assert not [error for error in errors if not error.startswith(own_blob)], errors
            with pytest.raises(PlaywrightError, match="violates the following Content Security"):
                page.add_script_tag(content="window.injected = true")
            assert page.evaluate("window.injected === undefined")
            page.close()
