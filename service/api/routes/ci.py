"""Continuous integration: a metric's history over commits with its step changes."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query
from fastapi.exceptions import RequestValidationError

from jobs.ci.history import MAX_HISTORY_RUNS, STEP_ALPHA, build_history
from metrics.registry import BY_NAME
from renderers.methods import METHODS
from renderers.scenes import builtin_names
from service.api.deps import StoreDep
from service.api.schemas import HistoryOut
from service.api.unprocessable import unprocessable

router = APIRouter(prefix="/api/v1/ci", tags=["ci"])

#: A name or a filter: printable, no NUL (PostgreSQL rejects it in strings).
Name = Annotated[str, Query(min_length=1, max_length=500, pattern=r"^[^\x00]*$")]
Filter = Annotated[str | None, Query(min_length=1, max_length=500, pattern=r"^[^\x00]*$")]
Resolution = Annotated[str | None, Query(pattern=r"^[1-9]\d{0,4}(x[1-9]\d{0,4})?$",
                                         description="WIDTHxHEIGHT, or one number for a "
                                                     "square image")]


def _unknown(message: str, name: str) -> RequestValidationError:
    return unprocessable(message, ("query", name))


@router.get("/history", response_model=HistoryOut)
def history(store: StoreDep, metric: Name, scene: Name, method: Name,
            branch: Filter = None, res: Resolution = None, device: Filter = None,
            limit: Annotated[int, Query(ge=1, le=500, description="commits per series, "
                                                                  "newest")] = 100,
            alpha: Annotated[float, Query(gt=0, lt=1, allow_inf_nan=False,
                                          description="family-wise error rate of the step "
                                                      "test")]
            = STEP_ALPHA) -> HistoryOut:
    """The metric's values per commit of one method on one scene (median over the seeds of
    the commit's runs, an interval for it, n), one series per setting (resolution, spp,
    frames, parameters), with version breaks and detected step changes marked
    (jobs/ci/history.py; docs/service.md, "CI history")."""
    if metric not in BY_NAME:
        raise _unknown(f"unknown metric {metric!r}; available: {', '.join(BY_NAME)}", "metric")
    if method not in METHODS and not store.has_runs(method=method):
        raise _unknown(f"unknown method {method!r}: not registered and no stored run has it; "
                       f"registered: {', '.join(METHODS)}", "method")
    if scene not in builtin_names() and not store.has_runs(scene=scene):
        raise _unknown(f"unknown scene {scene!r}: not a built-in scene (GET /api/v1/scenes) "
                       "and no stored run has it", "scene")
    resolution = None
    if res is not None:
        width, _, height = res.partition("x")
        resolution = (int(width), int(height or width))
    runs = store.list_history_runs(scene, method, limit=MAX_HISTORY_RUNS)
    return build_history(runs, BY_NAME[metric], scene=scene, method=method, branch=branch,
                         resolution=resolution, device=device, limit=limit, alpha=alpha)
