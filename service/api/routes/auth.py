"""The dashboard's login: an API key checked once, then kept in a cookie.

The cookie holds the key itself, HttpOnly (no page script can read it, so an
injected script cannot send it elsewhere), SameSite=Strict (no other site's page
makes the browser send it) and Secure when the service is reached over HTTPS. The
API accepts it for reads only; writes need the X-API-Key header (deps.py), so the
cookie cannot be used to submit or cancel jobs from a forged page.
"""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request, Response, status
from pydantic import BaseModel, Field

from jobs.execution.apikeys import verify_api_key
from service.api.deps import KEY_COOKIE, StoreDep

router = APIRouter(prefix="/api/v1/auth", tags=["auth"])

#: How long a browser keeps the login; a revoked key stops working at once anyway.
COOKIE_MAX_AGE_S = 30 * 24 * 3600


class Login(BaseModel):
    api_key: str = Field(min_length=1, max_length=200, description="an API key")


@router.post("/login", status_code=status.HTTP_204_NO_CONTENT)
def login(body: Login, request: Request, store: StoreDep) -> Response:
    """Check a key and keep it in the dashboard's HttpOnly, SameSite=Strict cookie."""
    if verify_api_key(store, body.api_key) is None:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "invalid or revoked API key")
    response = Response(status_code=status.HTTP_204_NO_CONTENT)
    response.set_cookie(KEY_COOKIE, body.api_key, max_age=COOKIE_MAX_AGE_S, path="/",
                        httponly=True, samesite="strict",
                        secure=request.url.scheme == "https")
    return response


@router.post("/logout", status_code=status.HTTP_204_NO_CONTENT)
def logout() -> Response:
    """Forget the dashboard's login cookie."""
    response = Response(status_code=status.HTTP_204_NO_CONTENT)
    response.delete_cookie(KEY_COOKIE, path="/", httponly=True, samesite="strict")
    return response
