"""Request dependencies: the app's store, queue and dispatcher; API-key checks.

Writes need the key in the ``X-API-Key`` header; a write route that acts on
behalf of the key takes it as :data:`CallerDep` (the key's row). Reads need a key
too unless the service runs with ``public_read`` (docs/security.md); a read also
accepts the dashboard's login cookie, which holds a session token (HttpOnly,
SameSite=Strict, set by ``POST /api/v1/auth/login``), never the key. Both are
declared as OpenAPI security schemes.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Depends, HTTPException, Path, Request, Security, status
from fastapi.security import APIKeyCookie, APIKeyHeader

from jobs.execution.apikeys import session_key, verify_api_key
from jobs.execution.queue import JobQueue
from jobs.record.models import ApiKey
from jobs.record.store import Store
from service.config import ServiceSettings


def get_settings(request: Request) -> ServiceSettings:
    return request.app.state.settings


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_queue(request: Request) -> JobQueue:
    return request.app.state.queue


def get_dispatcher(request: Request) -> Any:
    return request.app.state.dispatcher


#: The dashboard's login cookie, holding a session token (HttpOnly: page scripts cannot
#: read it).
SESSION_COOKIE = "nirc_bench_session"

api_key_header = APIKeyHeader(name="X-API-Key", auto_error=False,
                              description="an API key (`nirc-bench apikey create`)")
api_key_cookie = APIKeyCookie(name=SESSION_COOKIE, auto_error=False,
                              description="reads only: the dashboard's login session "
                                          "(POST /api/v1/auth/login)")


def _unauthorized(message: str) -> HTTPException:
    return HTTPException(status.HTTP_401_UNAUTHORIZED, message,
                         headers={"WWW-Authenticate": "X-API-Key"})


def _forbidden() -> HTTPException:
    return HTTPException(status.HTTP_403_FORBIDDEN, "invalid or revoked API key")


def require_api_key(store: Annotated[Store, Depends(get_store)],
                    x_api_key: Annotated[str | None, Security(api_key_header)] = None) -> ApiKey:
    """Write endpoints: the key in the X-API-Key header (401 without, 403 if wrong or
    revoked); returns its row."""
    if not x_api_key:
        raise _unauthorized("missing X-API-Key header")
    row = verify_api_key(store, x_api_key)
    if row is None:
        raise _forbidden()
    return row


def require_read_access(request: Request, store: Annotated[Store, Depends(get_store)],
                        x_api_key: Annotated[str | None, Security(api_key_header)] = None,
                        cookie: Annotated[str | None, Security(api_key_cookie)] = None) -> None:
    """Read endpoints of a service without public_read: the key in the header or a
    login session's cookie. Other methods are left to their own check (a write needs
    the header: a cookie, sent by the browser on its own, must not authorize one)."""
    if request.method not in ("GET", "HEAD"):
        return
    if x_api_key:
        if verify_api_key(store, x_api_key) is None:
            raise _forbidden()
        return
    if not cookie:
        raise _unauthorized("this service's results are not public: send an API key in "
                            "the X-API-Key header, or log in on the dashboard")
    if session_key(store, cookie) is None:
        raise _unauthorized("the dashboard's login has ended (logged out, expired, or its "
                            "key revoked): log in again")


StoreDep = Annotated[Store, Depends(get_store)]
QueueDep = Annotated[JobQueue, Depends(get_queue)]
SettingsDep = Annotated[ServiceSettings, Depends(get_settings)]
DispatcherDep = Annotated[Any, Depends(get_dispatcher)]
WriteAccess = Depends(require_api_key)
CallerDep = Annotated[ApiKey, Depends(require_api_key)]
ReadAccess = Depends(require_read_access)

#: A row id in a path: database integers are 32-bit on PostgreSQL.
RowId = Annotated[int, Path(ge=1, le=2**31 - 1)]
