"""Servers and programs the tests need, from the project's own setup scripts.

``make test`` runs the scripts once and passes their output in environment
variables; a plain ``pytest`` run calls them itself, and stops a server it started when
the run ends. Either way the tests run —
a missing PostgreSQL or Chromium is installed (as root with apt) or the test
fails with the script's message; it is never skipped.
"""

from __future__ import annotations

import atexit
import functools
import os
import subprocess
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


@functools.cache
def _from_script(variable: str, script: str) -> str:
    """What ``script`` prints; a server it says it started is stopped when the tests end
    (``script stop``)."""
    if os.environ.get(variable):
        return os.environ[variable]
    proc = subprocess.run(["bash", str(SCRIPTS / script)], capture_output=True, text=True)
    if proc.returncode != 0 or not proc.stdout.strip():
        pytest.fail(f"scripts/{script} could not provide {variable}: {proc.stderr.strip()}")
    if "started" in proc.stderr:
        atexit.register(subprocess.run, ["bash", str(SCRIPTS / script), "stop"],
                        capture_output=True, env=os.environ.copy())
    return proc.stdout.strip()


def postgres_server_url() -> str:
    """SQLAlchemy URL of the PostgreSQL test server (scripts/test_postgres.sh)."""
    return _from_script("NIRC_BENCH_TEST_PG_URL", "test_postgres.sh")


def chromium_path() -> str:
    """Path of the Chromium for the dashboard tests (scripts/test_browser.sh)."""
    return _from_script("NIRC_BENCH_TEST_CHROMIUM", "test_browser.sh")
