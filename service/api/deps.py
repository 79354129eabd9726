"""Request dependencies: the app's store, queue and dispatcher; API-key checks.

Writes need the key in the ``X-API-Key`` header. Reads need it too unless the
service runs with ``public_read`` (docs/security.md); a read also accepts the key
from the dashboard's login cookie (HttpOnly, SameSite=Strict, set by
``POST /api/v1/auth/login``). Both are declared as OpenAPI security schemes.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Depends, HTTPException, Path, Request, Security, status
from fastapi.security import APIKeyCookie, APIKeyHeader

from jobs.execution.apikeys import verify_api_key
from jobs.execution.queue import JobQueue
from jobs.record.config import Settings
from jobs.record.store import Store


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_queue(request: Request) -> JobQueue:
    return request.app.state.queue


def get_dispatcher(request: Request) -> Any:
    return request.app.state.dispatcher


#: The dashboard's login cookie, holding the key (HttpOnly: page scripts cannot read it).
KEY_COOKIE = "nirc_bench_key"

api_key_header = APIKeyHeader(name="X-API-Key", auto_error=False,
                              description="an API key (`nirc-bench apikey create`)")
api_key_cookie = APIKeyCookie(name=KEY_COOKIE, auto_error=False,
                              description="reads only: the key as the dashboard's login "
                                          "(POST /api/v1/auth/login) stored it")


def _check_key(store: Store, key: str | None, missing: str) -> None:
    """401 without a key, 403 with a wrong or revoked one."""
    if not key:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, missing,
                            headers={"WWW-Authenticate": "X-API-Key"})
    if verify_api_key(store, key) is None:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "invalid or revoked API key")


def require_api_key(store: Annotated[Store, Depends(get_store)],
                    x_api_key: Annotated[str | None, Security(api_key_header)] = None) -> None:
    """Write endpoints: the key in the X-API-Key header."""
    _check_key(store, x_api_key, "missing X-API-Key header")


def require_read_access(request: Request, store: Annotated[Store, Depends(get_store)],
                        x_api_key: Annotated[str | None, Security(api_key_header)] = None,
                        cookie: Annotated[str | None, Security(api_key_cookie)] = None) -> None:
    """Read endpoints of a service without public_read: the key in the header or the
    login cookie. Other methods are left to their own check (a write needs the header:
    a cookie, sent by the browser on its own, must not authorize one)."""
    if request.method not in ("GET", "HEAD"):
        return
    _check_key(store, x_api_key or cookie,
               "this service's results are not public: send an API key in the X-API-Key "
               "header, or log in on the dashboard")


StoreDep = Annotated[Store, Depends(get_store)]
QueueDep = Annotated[JobQueue, Depends(get_queue)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
DispatcherDep = Annotated[Any, Depends(get_dispatcher)]
WriteAccess = Depends(require_api_key)
ReadAccess = Depends(require_read_access)

#: A row id in a path: database integers are 32-bit on PostgreSQL.
RowId = Annotated[int, Path(ge=1, le=2**31 - 1)]
