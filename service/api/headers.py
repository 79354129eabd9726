"""Security headers on every answer of the app: the dashboard is a page of its own.

* ``Content-Security-Policy``: the dashboard's scripts, styles, images and API calls
  come from this service only (no inline script, no other origin); no page of another
  site may frame it (``frame-ancestors 'none'``). An injected ``<script>`` or an
  ``<img>`` pointing elsewhere does not run or load.
* ``X-Frame-Options: DENY`` for browsers that predate ``frame-ancestors``: a page of
  another site cannot lay the dashboard under its own clicks.
* ``X-Content-Type-Options: nosniff``: a stored artifact is served as its type, never
  guessed to be HTML or script; ``Referrer-Policy: no-referrer``: no URL of the
  service (job ids, scene names) leaves with a link.

The OpenAPI pages (``/docs``, ``/redoc``) load their viewer from this service (the
fastapi-offline package's copies, service/api/main.py) but start it with an inline
script: they get the other headers, not the CSP.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
    "connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; "
    "frame-ancestors 'none'")
HEADERS = [(b"x-frame-options", b"DENY"), (b"x-content-type-options", b"nosniff"),
           (b"referrer-policy", b"no-referrer")]
#: Paths of the OpenAPI viewers, whose pages start them inline (no CSP there).
VIEWER_PATHS = ("/docs", "/redoc")


class SecurityHeaders:
    """ASGI middleware adding the headers above to every HTTP answer."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        extra = list(HEADERS)
        if not scope["path"].startswith(VIEWER_PATHS):
            extra.append((b"content-security-policy", CONTENT_SECURITY_POLICY.encode()))

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", []), *extra]
            await send(message)

        await self.app(scope, receive, with_headers)
