"""The FastAPI application: REST API (OpenAPI at /docs and /redoc, served offline) over
the job store and queue.

``create_app(settings, dispatcher)`` builds the app; the service (``nirc-bench
serve``) passes a :class:`jobs.execution.dispatch.Dispatcher`, tests may pass None (jobs
stay queued) or a stand-in. On start, and then every ``redispatch_interval_s``, every
job that nothing runs is dispatched again: queued ones run, and running ones left by
a killed process, or given up by a runner that could not write the database, are
taken over once their heartbeat lease expires (jobs.execution.queue); every
``retention_interval_h`` the retention of `nirc-bench gc` is applied
(service/retention.py). A storage
failure is answered in JSON: 507 when the service cannot write (disk full), 503
while the database is unavailable (service/api/failures.py). A request that fails validation is
answered 422 with the errors as JSON, even when the bad value is NaN or Infinity
(which a JSON body may carry, but a JSON answer cannot), and with any echoed input
cut short; every 422 has that one shape (service/api/unprocessable.py; the body
limits: service/api/limits.py, its nesting depth: service/api/nesting.py).

Reads need an API key unless ``settings.public_read`` (service/config.py) (None counts as on: the app
alone does not know where it listens, and ``serve`` decides None before it gets
here, refusing a non-loopback address without an explicit choice). Likewise the
service answers only requests whose Host header names one of
``settings.allowed_hosts`` (400 otherwise: DNS rebinding); None accepts any host here,
and ``serve`` decides it before (loopback names and its own address).
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from fastapi import Depends, FastAPI
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline
from starlette.middleware.trustedhost import TrustedHostMiddleware

from jobs.execution.queue import JobQueue
from jobs.record.config import Settings
from jobs.record.db import open_store
from service.api import vendor
from service.api.deps import ReadAccess
from service.api.failures import add_failure_handlers
from service.api.headers import SecurityHeaders, viewer_policy
from service.api.limits import BodySizeLimit, bounded_json_body
from service.api.nesting import JsonDepthLimit
from service.api.quota import add_no_room_handler
from service.api.routes import (
    auth,
    charts,
    ci,
    images,
    jobs,
    pixels,
    reproductions,
    results,
    scenes,
)
from service.api.unprocessable import validation_failed
from service.config import ServiceSettings, host_patterns
from service.retention import start_retention

#: The dashboard's files (HTML, CSS, JavaScript, the vendored image slider): served
#: from here, never from a CDN; the chart library from service/api/vendor.py.
DASHBOARD_DIR = Path(__file__).resolve().parent.parent / "dashboard"


def _write_operations_need_the_header(app: FastAPI) -> None:
    """OpenAPI: the login cookie is accepted for reads only (deps.require_read_access),
    so a write operation lists the header scheme alone."""
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        schema = generate()
        for operations in schema.get("paths", {}).values():
            for method, operation in operations.items():
                if method not in ("get", "head") and "security" in operation:
                    operation["security"] = [requirement for requirement in
                                             operation["security"]
                                             if "APIKeyCookie" not in requirement]
        return schema

    app.openapi = openapi  # type: ignore[method-assign]


def create_app(settings: Settings | None = None, dispatcher: Any = None) -> FastAPI:
    """The app over the store of ``settings``: the service's own settings, or a store's
    completed with the service's from the environment (ServiceSettings.of)."""
    settings = ServiceSettings.of(settings) if settings is not None else ServiceSettings()
    store = open_store(settings)     # migrates the database before the first request
    queue = JobQueue(store)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        stops = [start_retention(store, settings)]
        if dispatcher is not None:
            dispatcher.recover()
            stops.append(dispatcher.recover_every(settings.redispatch_interval_s))
        try:
            yield
        finally:
            for stop in stops:
                if stop is not None:
                    stop.set()
            store.close()

    # Swagger UI (/docs) and ReDoc (/redoc) load their scripts and styles from the
    # installed fastapi-offline package, under /static-offline-docs: they work offline.
    # ReDoc's script comes through service/api/vendor.py, without its remote logo. The
    # pages are built once here, so that their Content-Security-Policy can allow
    # Swagger UI's inline start script by its hash (service/api/headers.py).
    app = FastAPIOffline(title="nirc-bench", version="1",
                  description="Evaluate and benchmark radiance-caching renderers: submit "
                              "render jobs and sweeps, poll them, read results.",
                  lifespan=lifespan, docs_url=None, redoc_url=None)
    openapi_url = app.openapi_url or "/openapi.json"
    viewers = {
        "/docs": get_swagger_ui_html(
            openapi_url=openapi_url, title="nirc-bench - Swagger UI",
            swagger_js_url="/static-offline-docs/swagger-ui-bundle.js",
            swagger_css_url="/static-offline-docs/swagger-ui.css",
            swagger_favicon_url="/static-offline-docs/favicon.png").body,
        "/redoc": get_redoc_html(openapi_url=openapi_url, title="nirc-bench - ReDoc",
                                 redoc_js_url=vendor.REDOC_PATH,
                                 redoc_favicon_url="/static-offline-docs/favicon.png",
                                 with_google_fonts=False).body}
    for path, page in viewers.items():
        app.add_api_route(path, lambda page=page: HTMLResponse(page), methods=["GET"],
                          include_in_schema=False)

    app.state.settings, app.state.store, app.state.queue = settings, store, queue
    app.state.dispatcher = dispatcher
    app.state.scene_parses = asyncio.Semaphore(settings.max_scene_parses)
    app.add_exception_handler(RequestValidationError, validation_failed)
    add_failure_handlers(app)
    add_no_room_handler(app)
    # A scene upload reads its body under its own cap (the scenes' size limit) and
    # checks its own nesting. The depth check runs inside the size limit, which bounds
    # the body it reads.
    upload = (("POST", scenes.UPLOAD_PATH),)
    app.add_middleware(JsonDepthLimit, exempt=upload)
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_body_bytes, exempt=upload)
    if settings.allowed_hosts is not None:
        app.add_middleware(TrustedHostMiddleware, www_redirect=False,
                           allowed_hosts=host_patterns(settings.allowed_hosts))
    app.add_middleware(SecurityHeaders, viewer_csp=viewer_policy(
        page.decode() for page in viewers.values()))
    guards = [Depends(bounded_json_body)]
    if settings.public_read is False:
        guards.append(ReadAccess)
    app.include_router(jobs.router, dependencies=guards)
    app.include_router(reproductions.router, dependencies=guards)
    app.include_router(results.router, dependencies=guards)
    app.include_router(ci.router, dependencies=guards)
    app.include_router(charts.router, dependencies=guards)
    app.include_router(pixels.router, dependencies=guards)
    app.include_router(images.router, dependencies=guards)
    app.include_router(auth.router, dependencies=[Depends(bounded_json_body)])
    app.include_router(scenes.router)
    _write_operations_need_the_header(app)
    app.include_router(vendor.router)
    vendor.warm_up()
    app.mount("/static", StaticFiles(directory=DASHBOARD_DIR), name="static")

    @app.get("/", include_in_schema=False)
    def dashboard() -> FileResponse:
        return FileResponse(DASHBOARD_DIR / "index.html", media_type="text/html")

    return app
