"""The FastAPI application: REST API (OpenAPI at /docs) over the job store and queue.

``create_app(settings, dispatcher)`` builds the app; the service (``nirc-bench
serve``) passes a :class:`jobs.dispatch.Dispatcher`, tests may pass None (jobs
stay queued) or a stand-in. On start every unfinished job is dispatched again:
queued ones run, and running ones left by a killed process are taken over when
their heartbeat lease expires (jobs.queue).
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

from jobs.config import Settings
from jobs.db import open_store
from jobs.queue import JobQueue
from service.api.routes import jobs, results

#: The dashboard's files (HTML, CSS, JavaScript with its own SVG plots): served from
#: here, never from a CDN.
DASHBOARD_DIR = Path(__file__).resolve().parent.parent / "dashboard"


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
    app.include_router(jobs.router)
    app.include_router(results.router)
    app.mount("/static", StaticFiles(directory=DASHBOARD_DIR), name="static")

    @app.get("/", include_in_schema=False)
    def dashboard() -> FileResponse:
        return FileResponse(DASHBOARD_DIR / "index.html", media_type="text/html")

    return app
