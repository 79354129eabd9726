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
fastapi-offline package's copies, service/api/main.py); ``/docs`` starts it with an
inline script and both viewers add ``<style>`` elements as they draw. They get a
policy of their own (:func:`viewer_policy`): the same sources, their inline start
script allowed by its SHA-256 only (no other inline script runs), inline styles,
ReDoc's search worker.

A 500 is written outside every middleware (Starlette's error middleware, which
calls service/api/failures.py's handler): it takes :func:`security_headers` itself.
"""

from __future__ import annotations

import base64
import hashlib
import re
from collections.abc import Iterable

from starlette.types import ASGIApp, Message, Receive, Scope, Send

CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
    "connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; "
    "frame-ancestors 'none'")
HEADERS = [(b"x-frame-options", b"DENY"), (b"x-content-type-options", b"nosniff"),
           (b"referrer-policy", b"no-referrer")]
#: Paths of the OpenAPI viewers, whose pages start them inline (their own policy).
VIEWER_PATHS = ("/docs", "/redoc")
_INLINE_SCRIPT = re.compile(r"<script>(.*?)</script>", re.DOTALL)


def viewer_policy(pages: Iterable[str]) -> str:
    """The CSP of the viewer ``pages`` (their HTML): the dashboard's, but each inline
    ``<script>`` of theirs allowed by its hash, inline styles, and workers from
    ``blob:`` URLs (ReDoc's search runs in one it builds)."""
    hashes = sorted({"'sha256-" + base64.b64encode(hashlib.sha256(script.encode()).digest())
                     .decode() + "'" for page in pages for script in _INLINE_SCRIPT.findall(page)})
    return (CONTENT_SECURITY_POLICY
            .replace("script-src 'self'", " ".join(["script-src 'self'", *hashes]))
            .replace("style-src 'self'", "style-src 'self' 'unsafe-inline'")
            + "; worker-src 'self' blob:")


def security_headers(path: str, viewer_csp: str = "") -> list[tuple[bytes, bytes]]:
    """The headers of an answer at ``path`` (``viewer_csp``: the viewers' policy)."""
    policy = viewer_csp if path.startswith(VIEWER_PATHS) else CONTENT_SECURITY_POLICY
    return [*HEADERS, *([(b"content-security-policy", policy.encode())] if policy else [])]


class SecurityHeaders:
    """ASGI middleware adding the headers above to every HTTP answer."""

    def __init__(self, app: ASGIApp, viewer_csp: str = "") -> None:
        self.app, self.viewer_csp = app, viewer_csp

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        extra = security_headers(scope["path"], self.viewer_csp)

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", []), *extra]
            await send(message)

        await self.app(scope, receive, with_headers)
