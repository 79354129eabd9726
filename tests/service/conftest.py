"""Fixtures of the service tests: a real headless Chromium (Debian's, via Playwright);
the database of a test run on both SQLite and PostgreSQL."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import uvicorn

from tests.pg import postgres_database
from tests.setup_services import chromium_path

#: Screenshots of the dashboard tests (kept as test artefacts; gitignored).
ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts"
CHROMIUM_FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update",
                  "--disable-sync"]


@pytest.fixture(scope="session")
def chromium():
    from playwright.sync_api import sync_playwright

    path = chromium_path()
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=path, args=CHROMIUM_FLAGS)
        yield browser
        browser.close()


def open_page(chromium, url: str):
    """A page at ``url`` and the list its console errors, uncaught exceptions and
    requests to any other origin than ``url``'s go to (the dashboard loads nothing from
    elsewhere)."""
    page = chromium.new_page(viewport={"width": 1300, "height": 1800})
    errors: list[str] = []
    origin = "/".join(url.split("/")[:3]) + "/"
    page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
    page.on("pageerror", lambda err: errors.append(str(err)))
    page.on("request", lambda request: None if request.url.startswith((origin, "data:"))
            else errors.append(f"request to another origin: {request.url}"))
    page.goto(url)
    return page, errors


def wait_until(page, expression: str, timeout_s: float = 30.0) -> None:
    """Wait until the JavaScript ``expression`` is true in ``page``. Polled from here:
    Playwright's own wait_for_function evaluates its predicate with ``eval`` inside the
    page, which the dashboard's Content-Security-Policy (no 'unsafe-eval') forbids."""
    deadline = time.monotonic() + timeout_s
    while not page.evaluate(expression):
        if time.monotonic() > deadline:
            raise AssertionError(f"still false after {timeout_s:g} s: {expression}")
        time.sleep(0.1)


@contextmanager
def serve(app) -> Iterator[str]:
    """``app`` served on a free loopback port in a thread; yields its base URL."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port,
                                           log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=10)


@pytest.fixture(params=["sqlite", "postgresql"])
def database_url(request):
    """None (SQLite in the test's data folder) or a fresh PostgreSQL database's URL."""
    if request.param == "sqlite":
        yield None
        return
    with postgres_database() as url:
        yield url


@pytest.fixture
def api_and_store(request, tmp_path, monkeypatch, database_url):
    """(in-process API client without a dispatcher, its store) on each test database
    (SQLite: a copy of the migrated one, tests/conftest.py): for tests that store runs
    directly and read them back over REST."""
    from fastapi.testclient import TestClient

    from jobs.record.config import Settings
    from jobs.record.db import open_store
    from service.api.main import create_app

    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    data = tmp_path / "data" if database_url else request.getfixturevalue("data_folder")
    settings = Settings(data_dir=data, database_url=database_url)
    store = open_store(settings)
    with TestClient(create_app(settings)) as http:
        yield http, store
    store.close()
