"""What computed a result: estimator and metric-definition versions.

Every stored result (run, reference, cache snapshot, sweep) records the version
of the estimator that rendered it and of the metric definitions that scored
it, and both are part of every dedupe key, so a result of an older version is
never reused. Version 1 stands for everything stored before versions were
recorded (the database migration gives old rows 1).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from jobs.protocol.provenance import library_versions
from metrics import METRIC_VERSION
from renderers.methods import METHODS, get_method


def estimator_version(method: str) -> int:
    """The registry's current version of ``method`` (MethodError if unknown)."""
    return get_method(method).version


def current_estimator_versions() -> dict[str, int]:
    """Method name -> its current estimator version, for every registered method."""
    return {name: method.version for name, method in METHODS.items()}


def reference_estimator_version(integrator: str) -> str:
    """Version of a reference integrator: Mitsuba's own ``path`` is versioned by the
    mitsuba library, our ``pt`` by its estimator version."""
    if integrator == "path":
        return f"mitsuba {library_versions()['mitsuba']}"
    return f"{integrator} {estimator_version(integrator)}"


def sweep_estimator_versions(methods: Iterable[str]) -> dict[str, int]:
    """The estimator versions a sweep over ``methods`` runs under."""
    return {method: estimator_version(method) for method in methods}


def versions_of(method: str) -> dict[str, int]:
    """The versions a new result of ``method`` is stored with (and keyed by)."""
    return {"estimator_version": estimator_version(method), "metric_version": METRIC_VERSION}


def is_current(method: str, estimator: Any, metric: Any) -> bool:
    """Whether a stored result of ``method`` was computed by today's versions."""
    return (metric == METRIC_VERSION and method in METHODS
            and estimator == METHODS[method].version)
