"""The dashboard's login: an API key checked once, then a server-side session.

The key goes to the service once; the cookie then holds a random session token
whose digest the database keeps with the key's id and an expiry
(jobs/execution/apikeys.py), never the key: a cookie that leaks is worth one
session, which ends at logout, at expiry (``session_max_age_s``) or when the key
is revoked. The cookie is HttpOnly (no page script can read it), SameSite=Strict
(no other site's page makes the browser send it) and Secure when the service is
reached over HTTPS. The API accepts it for reads only; writes need the X-API-Key
header (deps.py), so the cookie cannot be used to submit or cancel jobs from a
forged page.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, HTTPException, Request, Response, Security, status
from pydantic import BaseModel, Field

from jobs.execution.apikeys import end_session, start_session, verify_api_key
from service.api.deps import SESSION_COOKIE, SettingsDep, StoreDep, api_key_cookie

router = APIRouter(prefix="/api/v1/auth", tags=["auth"])


class Login(BaseModel):
    api_key: str = Field(min_length=1, max_length=200, description="an API key")


@router.post("/login", status_code=status.HTTP_204_NO_CONTENT)
def login(body: Login, request: Request, store: StoreDep, settings: SettingsDep) -> Response:
    """Check a key and start a session held by the dashboard's HttpOnly, SameSite=Strict
    cookie."""
    key = verify_api_key(store, body.api_key)
    if key is None:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "invalid or revoked API key")
    token = start_session(store, key, settings.session_max_age_s)
    response = Response(status_code=status.HTTP_204_NO_CONTENT)
    response.set_cookie(SESSION_COOKIE, token, max_age=round(settings.session_max_age_s),
                        path="/", httponly=True, samesite="strict",
                        secure=request.url.scheme == "https")
    return response


@router.post("/logout", status_code=status.HTTP_204_NO_CONTENT)
def logout(store: StoreDep,
           cookie: Annotated[str | None, Security(api_key_cookie)] = None) -> Response:
    """End the dashboard's session (on the server too) and forget its cookie."""
    end_session(store, cookie)
    response = Response(status_code=status.HTTP_204_NO_CONTENT)
    response.delete_cookie(SESSION_COOKIE, path="/", httponly=True, samesite="strict")
    return response
