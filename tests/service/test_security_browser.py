"""What a web page in a browser on the service's machine can make of it, replayed
against the in-process app: reading it through a domain of its own that resolves to
loopback (DNS rebinding: any Host header was answered 200)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from jobs.record.db import open_store
from service.api.main import create_app
from service.cli import decide_allowed_hosts
from service.config import ServiceSettings
from service.errors import UsageError


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
