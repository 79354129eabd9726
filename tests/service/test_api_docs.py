"""The OpenAPI pages work offline (every script and style from this service), and a
sweep over REST takes the CLI's 'a:b:step' eps form as well as a list."""

from __future__ import annotations

import re
from pathlib import Path

from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key
from jobs.record.config import Settings
from jobs.record.db import open_store
from service.api.main import create_app
from service.api.vendor import REMOTE_IMAGE, redoc_script


def _client(tmp_path, monkeypatch) -> tuple[TestClient, str]:
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    settings = Settings(data_dir=tmp_path / "data")
    _, key = create_api_key(open_store(settings), "tests")
    return TestClient(create_app(settings, None)), key


def test_docs_and_redoc_load_nothing_from_another_host(tmp_path, monkeypatch):
    client, _ = _client(tmp_path, monkeypatch)
    with client:
        for page in ("/docs", "/redoc"):
            html = client.get(page)
            assert html.status_code == 200
            links = re.findall(r'(?:src|href)\s*=\s*["\']([^"\']+)', html.text)
            links += re.findall(r"url:\s*'([^']+)'", html.text)
            assert links, page
            for link in links:
                assert link.startswith("/"), f"{page} loads {link} from elsewhere"
                assert client.get(link).status_code == 200, link
            assert "cdn" not in html.text.lower() and "//fonts." not in html.text
            # The viewers' scripts fetch no image of another host (ReDoc's footer logo).
            for script in (link for link in links if link.endswith(".js")):
                assert not REMOTE_IMAGE.search(client.get(script).content), script


def test_the_remote_image_pattern_finds_the_packaged_viewers_logo():
    """Planted: the package's own ReDoc script loads its footer logo from a CDN, which
    the pattern the test above checks with finds; the served copy has none."""
    import fastapi_offline

    packaged = (Path(fastapi_offline.__file__).parent / "static" / "redoc.standalone.js")
    assert REMOTE_IMAGE.search(packaged.read_bytes())
    assert not REMOTE_IMAGE.search(redoc_script())


def test_a_sweep_takes_the_range_text_the_cli_takes(tmp_path, monkeypatch):
    client, key = _client(tmp_path, monkeypatch)
    client.headers["X-API-Key"] = key
    with client:
        spec = {"scene": "cornell-box", "eps": "0.05:0.2", "nc": "1,2", "seeds": 2,
                "resolution": 8}
        made = client.post("/api/v1/sweeps", json=spec)
        assert made.status_code == 202, made.text
        job = client.get(made.headers["Location"]).json()
        assert job["spec"]["eps"] == [0.05, 0.1, 0.15, 0.2] and job["spec"]["nc"] == [1, 2]
        bad = client.post("/api/v1/sweeps", json={**spec, "eps": "1:b:2"})
        assert bad.status_code == 422 and "'b' is not a number" in bad.text
