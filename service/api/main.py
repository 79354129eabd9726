"""The FastAPI application: REST API (OpenAPI at /docs) over the job store and queue.

``create_app(settings, dispatcher)`` builds the app; the service (``nirc-bench
serve``) passes a :class:`jobs.dispatch.Dispatcher`, tests may pass None (jobs
stay queued) or a stand-in. On start every unfinished job is dispatched again:
queued ones run, and running ones left by a killed process are taken over when
their heartbeat lease expires (jobs.queue). A request that fails validation is
answered 422 with the errors as JSON, even when the bad value is NaN or Infinity
(which a JSON body may carry, but a JSON answer cannot).
"""

from __future__ import annotations

import math
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request, status
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

from jobs.config import Settings
from jobs.db import open_store
from jobs.queue import JobQueue
from service.api.routes import jobs, results, scenes

#: The dashboard's files (HTML, CSS, JavaScript with its own SVG plots): served from
#: here, never from a CDN.
DASHBOARD_DIR = Path(__file__).resolve().parent.parent / "dashboard"


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
    """FastAPI's 422 answer, which would fail with a 500 on a NaN it has to echo."""
    return JSONResponse(status_code=status.HTTP_422_UNPROCESSABLE_CONTENT,
                        content={"detail": _json_safe(jsonable_encoder(exc.errors()))})


def create_app(settings: Settings | None = None, dispatcher: Any = None) -> FastAPI:
    settings = settings or Settings()
    store = open_store(settings)     # migrates the database before the first request
    queue = JobQueue(store)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        if dispatcher is not None:
            for job_id in queue.unfinished():
                dispatcher.submit(queue.get(job_id))
        try:
            yield
        finally:
            store.close()

    app = FastAPI(title="nirc-bench", version="1",
                  description="Evaluate and benchmark radiance-caching renderers: submit "
                              "render jobs and sweeps, poll them, read results.",
                  lifespan=lifespan)
    app.state.settings, app.state.store, app.state.queue = settings, store, queue
    app.state.dispatcher = dispatcher
    app.add_exception_handler(RequestValidationError, validation_failed)
    app.include_router(jobs.router)
    app.include_router(results.router)
    app.include_router(scenes.router)
    app.mount("/static", StaticFiles(directory=DASHBOARD_DIR), name="static")

    @app.get("/", include_in_schema=False)
    def dashboard() -> FileResponse:
        return FileResponse(DASHBOARD_DIR / "index.html", media_type="text/html")

    return app
