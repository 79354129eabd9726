"""Provenance stored with every result: library versions, the project commit and branch."""

from __future__ import annotations

import os
import subprocess
from functools import cache
from importlib import metadata
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parent.parent
# pyoidn: the denoiser of the denoised errors (its own version; it ships OIDN's, which a
# denoised run also stores under metrics['denoiser']).
_LIBRARIES = ("nirc-bench", "mitsuba", "drjit", "numpy", "flip-evaluator", "OpenEXR",
              "colour-science", "sqlalchemy", "pyoidn")


def library_versions() -> dict[str, str]:
    """The installed versions of the libraries a result depends on (a copy)."""
    return dict(_installed_versions())


@cache
def _installed_versions() -> dict[str, str]:
    # Read once per process: the modules a process has loaded do not change with a
    # later install, and reading the packages' metadata costs ~30 ms (per job).
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


@cache
def git_branch() -> str | None:
    """The branch the project checkout is on: ``NIRC_BENCH_BRANCH`` if set, else the CI
    system's (``GITHUB_HEAD_REF`` of a pull request, ``GITHUB_REF_NAME``, ``CI_COMMIT_REF_NAME``),
    else git's current branch; None on a detached HEAD or without a checkout."""
    for name in ("NIRC_BENCH_BRANCH", "GITHUB_HEAD_REF", "GITHUB_REF_NAME", "CI_COMMIT_REF_NAME"):
        if os.environ.get(name):
            return os.environ[name]
    try:
        branch = subprocess.run(["git", "-C", str(PROJECT_ROOT), "rev-parse", "--abbrev-ref",
                                 "HEAD"], capture_output=True, text=True, timeout=10,
                                check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return None if branch in ("", "HEAD") else branch
