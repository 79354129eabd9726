"""The embedded Dask cluster listens on no HTTP port unless its dashboards are asked
for: Dask starts an HTTP server in its scheduler and in every worker (dashboard, info
pages with the workers' logs and call stacks, health, metrics), open to every account
of the machine. With ``dashboard=True`` (``serve --dask-dashboard``) they stay, on
loopback: the control that shows the check sees them."""

from __future__ import annotations

import httpx
import psutil
import pytest

from jobs.execution.dispatch import Dispatcher
from jobs.record.config import Settings


def _listening() -> set[tuple[str, int]]:
    """The TCP addresses this process and its children listen on."""
    root = psutil.Process()
    return {(conn.laddr.ip, conn.laddr.port)
            for process in (root, *root.children(recursive=True))
            for conn in process.net_connections(kind="tcp")
            if conn.status == psutil.CONN_LISTEN}


@pytest.mark.parametrize("dashboard", [False, True], ids=["default", "asked-for"])
def test_the_embedded_cluster_serves_http_only_when_asked(tmp_path, monkeypatch, dashboard):
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    before = _listening()
    dispatcher = Dispatcher(Settings(data_dir=tmp_path / "data"), gpus=0, dashboard=dashboard)
    try:
        opened = _listening() - before
        if not dashboard:
            assert opened == set()
            assert dispatcher.dashboard_url is None
            return
        assert opened and {ip for ip, _ in opened} == {"127.0.0.1"}, opened
        for _, port in opened:      # the scheduler's and the worker's
            assert httpx.get(f"http://127.0.0.1:{port}/health", timeout=10).text == "ok"
        assert httpx.get(dispatcher.dashboard_url, timeout=10).status_code == 200
    finally:
        dispatcher.close()
