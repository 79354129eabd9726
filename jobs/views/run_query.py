"""Finding stored runs: filters, sorting and columns of ``nirc-bench runs list``.

The database filters what it can (scene, method, device, commit or branch, dates);
method parameters (stored as JSON) and tags are compared here, so ``nc=4`` matches a
run whose resolved ``nc`` is 4 whatever the database.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, Field

from jobs.protocol.labels import changed_params
from jobs.protocol.results import RunResult
from jobs.record.store import Store


class RunQueryError(ValueError):
    """A filter, sort key or column that names nothing a run has."""


class RunFilter(BaseModel):
    """What ``runs list`` keeps (every given filter must match)."""

    scene: str | None = None
    method: str | None = None
    device: str | None = None
    commit: str | None = Field(None, description="a commit prefix or a branch name")
    since: datetime | None = None
    until: datetime | None = None
    params: dict[str, Any] = Field(default_factory=dict)
    tags: dict[str, str] = Field(default_factory=dict)
    name: str | None = None


#: Columns computed from a row: the parameters that differ from the method's defaults,
#: and milliseconds per frame.
DERIVED_COLUMNS = ("changed", "ms")
#: The columns ``runs list`` may show and sort by (besides params.NAME and tags.NAME).
COLUMNS = (*RunResult.model_fields, *DERIVED_COLUMNS)


def check_column(column: str) -> str:
    """``column`` when a run has it, else RunQueryError listing what there is."""
    if column in COLUMNS or column.startswith(("params.", "tags.")):
        return column
    raise RunQueryError(f"unknown column '{column}'; a column is one of {', '.join(COLUMNS)}, "
                        "params.NAME or tags.NAME")


def run_value(row: RunResult, column: str) -> Any:
    """A column (:func:`check_column`) of a result row."""
    if column.startswith("params."):
        return row.params.get(column.removeprefix("params."))
    if column.startswith("tags."):
        return row.tags.get(column.removeprefix("tags."))
    if column == "changed":
        return " ".join(f"{name}={value}" for name, value in
                        changed_params(row.method, row.params).items())
    if column == "ms":
        return None if row.seconds_per_frame is None else 1e3 * row.seconds_per_frame
    return getattr(row, check_column(column))


def _matches(row: RunResult, where: RunFilter) -> bool:
    if where.name is not None and row.name != where.name:
        return False
    if any(row.tags.get(key) != value for key, value in where.tags.items()):
        return False
    return all(row.params.get(key) == value for key, value in where.params.items())


def find_runs(store: Store, where: RunFilter, *, sort: str = "-created_at",
              limit: int | None = 50) -> list[RunResult]:
    """The stored runs ``where`` keeps, sorted by ``sort`` (a column; '-' first for
    descending; runs without a value last), at most ``limit``."""
    descending = sort.startswith("-")
    key = check_column(sort.removeprefix("-"))
    rows = [RunResult.of(run) for run in store.list_runs(
        where.scene, where.method, where.device, git_ref=where.commit,
        created_after=where.since, created_before=where.until)]
    rows = [row for row in rows if _matches(row, where)]
    present = [row for row in rows if run_value(row, key) is not None]
    absent = [row for row in rows if run_value(row, key) is None]
    try:
        present.sort(key=lambda row: run_value(row, key), reverse=descending)
    except TypeError:   # mixed types (a parameter that is a number here, a list there)
        present.sort(key=lambda row: str(run_value(row, key)), reverse=descending)
    rows = present + absent
    return rows if limit is None else rows[:limit]
