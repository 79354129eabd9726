"""Errors a user can cause, and how they are described in one line."""

from __future__ import annotations

from pydantic import ValidationError

from jobs.execution.gpus import GpuError
from jobs.protocol.comparison import ComparisonError
from jobs.protocol.ranges import RangeError
from jobs.protocol.run_query import RunQueryError
from jobs.record.db import SchemaVersionError
from metrics.errors import MetricError
from metrics.imageio import ImageReadError
from renderers.backend import BackendError
from renderers.methods import MethodError, format_validation_error
from renderers.scenes import SceneError
from service.client import RemoteError


class UsageError(ValueError):
    """A command was used wrongly in a way its options cannot check."""


USER_ERRORS: tuple[type[BaseException], ...] = (
    BackendError, SceneError, MethodError, ImageReadError, MetricError, SchemaVersionError,
    ValidationError, FileNotFoundError, RangeError, RemoteError, UsageError, GpuError,
    RunQueryError, ComparisonError,
)


def describe_user_error(err: BaseException) -> str:
    if isinstance(err, ValidationError):
        return f"invalid {err.title}: {format_validation_error(err)}"
    if isinstance(err, FileNotFoundError):
        return f"file not found: {err.filename or err}"
    return str(err)
