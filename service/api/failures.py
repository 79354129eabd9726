"""Answers for failures that are not the client's: always JSON, never a traceback.

* The service cannot write (a full disk, a quota, a file size limit; the database
  full): **507** with the cause, e.g. ``{"detail": "storage full: ..."}``, the file it
  names relative to the data folder (service/api/data_paths.py).
* The database is unavailable (locked past its timeout, the connection lost):
  **503** with ``Retry-After``; the request changed nothing and may be sent again.
* Anything else unexpected: **500** ``{"detail": "internal error ..."}``, logged
  with its traceback by the server.

Classification: jobs/record/storage.py.
"""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request, status
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DBAPIError
from sqlalchemy.exc import TimeoutError as PoolTimeout

from jobs.record.storage import describe, storage_failure
from service.api.data_paths import served
from service.api.headers import security_headers

log = logging.getLogger(__name__)

#: Seconds a client is asked to wait before retrying while the database is unavailable.
RETRY_AFTER_S = 5


async def storage_failed(request: Request, exc: Exception) -> JSONResponse:
    kind = storage_failure(exc)
    if kind == "full":
        detail = served(describe(exc), request.app.state.settings.data_dir)
        return JSONResponse({"detail": detail}, status_code=status.HTTP_507_INSUFFICIENT_STORAGE)
    if kind == "unavailable":
        return JSONResponse({"detail": f"{describe(exc)}; try again shortly"},
                            status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
                            headers={"Retry-After": str(RETRY_AFTER_S)})
    return internal_error(request, exc)


def internal_error(request: Request, exc: Exception) -> JSONResponse:
    log.error("internal error answering %s %s", request.method, request.url.path,
              exc_info=exc)
    return JSONResponse({"detail": f"internal error ({type(exc).__name__}); the service's "
                                   "log has the details"},
                        status_code=status.HTTP_500_INTERNAL_SERVER_ERROR,
                        # Written outside the middleware that adds them elsewhere.
                        headers={name.decode(): value.decode() for name, value
                                 in security_headers(request.url.path)})


def add_failure_handlers(app: FastAPI) -> None:
    """Storage failures (OSError, database errors) as 507/503; any other exception as
    a JSON 500."""
    for kind in (OSError, DBAPIError, PoolTimeout):
        app.add_exception_handler(kind, storage_failed)
    app.add_exception_handler(Exception, internal_error)
