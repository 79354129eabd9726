"""Provenance stored with every result: library versions and the project commit."""

from __future__ import annotations

import os
import subprocess
from functools import cache
from importlib import metadata
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parent.parent
_LIBRARIES = ("nirc-bench", "mitsuba", "drjit", "numpy", "flip-evaluator", "OpenEXR",
              "colour-science", "sqlalchemy")


def library_versions() -> dict[str, str]:
    versions = {}
    for name in _LIBRARIES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


@cache
def git_commit() -> str:
    """HEAD of the project checkout, suffixed '-dirty' with uncommitted changes, or
    ``NIRC_BENCH_GIT_COMMIT`` where there is no checkout (a Docker image records the
    commit it was built from)."""
    if os.environ.get("NIRC_BENCH_GIT_COMMIT"):
        return os.environ["NIRC_BENCH_GIT_COMMIT"]

    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(PROJECT_ROOT), *args], capture_output=True,
                              text=True, timeout=10, check=True).stdout.strip()

    try:
        commit = git("rev-parse", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return commit + ("-dirty" if dirty else "")
