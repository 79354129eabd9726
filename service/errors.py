"""Errors a user can cause, and how they are described in one line.

They are known by the module and name of their classes, not by importing them: a
command cannot raise the error of a module it never loaded, and importing every such
module (SQLAlchemy and Alembic through the store, httpx through the client) cost
about 1 s of every CLI start, the commands that fail on their arguments included.
``tests/service/test_errors.py`` checks that every name is a class that exists.
"""

from __future__ import annotations


class UsageError(ValueError):
    """A command was used wrongly in a way its options cannot check."""


#: The classes of the errors a user can cause, as ``module.qualname`` (an exception is a
#: user error when one of its classes is named here).
USER_ERROR_CLASSES = frozenset({
    "renderers.backend.BackendError",
    "renderers.scenes.errors.SceneError",
    "renderers.methods.MethodError",
    "metrics.imageio.ImageReadError",
    "metrics.checks.MetricError",
    "jobs.record.db.SchemaVersionError",
    "pydantic_core._pydantic_core.ValidationError",
    "builtins.FileNotFoundError",
    "jobs.protocol.ranges.RangeError",
    "service.client.RemoteError",
    f"{__name__}.UsageError",
    "jobs.execution.gpus.GpuError",
    "jobs.views.run_query.RunQueryError",
    "jobs.views.comparison.ComparisonError",
    "jobs.protocol.calibration.LoadedMachineError",
    "jobs.record.reproduction_marker.FolderBusy",
})


def is_user_error(err: BaseException, *also: str) -> bool:
    """Whether ``err`` is an error a user can cause (or of a class named in ``also``)."""
    names = {f"{cls.__module__}.{cls.__qualname__}" for cls in type(err).__mro__}
    return not names.isdisjoint(USER_ERROR_CLASSES) or not names.isdisjoint(also)


def describe_user_error(err: BaseException) -> str:
    from pydantic import ValidationError

    if isinstance(err, ValidationError):
        from renderers.methods import format_validation_error

        return f"invalid {err.title}: {format_validation_error(err)}"
    if isinstance(err, FileNotFoundError):
        return f"file not found: {err.filename or err}"
    return str(err)
