"""A service app whose two API keys, ``a`` and ``b``, each have a test client."""

from __future__ import annotations

from typing import Any

from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key
from service.api.main import create_app


def two_key_clients(settings: Any, store: Any) -> tuple[TestClient, TestClient]:
    """(client of key a, client of key b) of an app on ``settings`` and ``store``'s
    database, with no dispatcher (jobs stay queued)."""
    app = create_app(settings, None)
    clients = []
    for name in ("a", "b"):
        client = TestClient(app)
        client.headers["X-API-Key"] = create_api_key(store, name)[1]
        clients.append(client)
    return clients[0], clients[1]
