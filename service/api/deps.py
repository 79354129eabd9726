"""Request dependencies: the app's store, queue and dispatcher; API-key checks."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Depends, Header, HTTPException, Path, Request, status

from jobs.apikeys import verify_api_key
from jobs.config import Settings
from jobs.queue import JobQueue
from jobs.store import Store


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_queue(request: Request) -> JobQueue:
    return request.app.state.queue


def get_dispatcher(request: Request) -> Any:
    return request.app.state.dispatcher


def require_api_key(store: Annotated[Store, Depends(get_store)],
                    x_api_key: Annotated[str | None, Header()] = None) -> None:
    """Write endpoints: 401 without a key, 403 with a wrong or revoked one."""
    if not x_api_key:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing X-API-Key header",
                            headers={"WWW-Authenticate": "X-API-Key"})
    if verify_api_key(store, x_api_key) is None:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "invalid or revoked API key")


StoreDep = Annotated[Store, Depends(get_store)]
QueueDep = Annotated[JobQueue, Depends(get_queue)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
DispatcherDep = Annotated[Any, Depends(get_dispatcher)]
WriteAccess = Depends(require_api_key)

#: A row id in a path: database integers are 32-bit on PostgreSQL.
RowId = Annotated[int, Path(ge=1, le=2**31 - 1)]
