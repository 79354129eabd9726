"""The one shape of a 422 answer, built in one place.

Every request the service cannot process as sent is answered 422 with FastAPI's
validation format, whichever part refused it (the request's validation, the body
limits, a route's own checks: a scene that may not be used, a job over the work
limits, an unknown name in a query, runs that cannot be compared)::

    {"detail": [{"loc": ["body", "spp"], "msg": "...", "type": "value_error",
                 "input": ..., "ctx": {...}}, ...]}

``loc`` says where the bad value is (``body``, ``query``, ``header`` and the field),
``msg`` what is wrong in the user's terms; ``input`` (the offending value, when
known) and ``ctx`` (figures such as an estimate and its limit) are optional. A route
raises :func:`unprocessable`; :func:`validation_failed` writes every answer, so a
NaN or Infinity it has to repeat is spelled as JSON spells it (instead of failing
with a 500) and a huge input is cut short (service/api/limits.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from fastapi import Request, status
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from service.api.limits import truncate_echo


def unprocessable(message: str, loc: Sequence[str | int] = ("body",), *,
                  type: str = "value_error",
                  ctx: dict[str, Any] | None = None) -> RequestValidationError:
    """The 422 of a value at ``loc`` (``("body", "scene")``, ``("query", "metric")``,
    ``("header", "Idempotency-Key")``) that ``message`` explains; raise it."""
    error: dict[str, Any] = {"loc": list(loc), "msg": message, "type": type}
    if ctx is not None:
        error["ctx"] = ctx
    return RequestValidationError([error])


def _json_safe(value: Any) -> Any:
    """``value`` with NaN and infinities spelled as the JSON body spelled them."""
    if isinstance(value, float) and not math.isfinite(value):
        return "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    if isinstance(value, dict):
        return {key: _json_safe(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_json_safe(item) for item in value]
    return value


async def validation_failed(request: Request, exc: RequestValidationError) -> JSONResponse:
    """Every 422 answer. FastAPI's own would fail with a 500 on a NaN it has to echo,
    and would repeat a huge input whole."""
    errors = [truncate_echo(error) for error in jsonable_encoder(exc.errors())]
    return JSONResponse(status_code=status.HTTP_422_UNPROCESSABLE_CONTENT,
                        content={"detail": _json_safe(errors)})
