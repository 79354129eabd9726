"""The nesting depth of a JSON body, bounded before anything parses it.

Python's JSON parser recurses once per nested array or object: a body nested about
a thousand deep makes it raise ``RecursionError``, which FastAPI answered 400 ("error
parsing the body") and the scene upload 500. So every body is scanned first, as
bytes, for arrays and objects nested deeper than ``MAX_DEPTH``
(service/api/limits.py; the body itself is level 1) and refused with the one 422
shape (service/api/unprocessable.py). The scan skips string contents (a bracket in
a string nests nothing) and costs one regular-expression pass over the brackets and
quotes, on a body already bounded by ``max_body_bytes``.
"""

from __future__ import annotations

import re

from fastapi import Request
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.api.limits import MAX_DEPTH
from service.api.unprocessable import unprocessable, validation_failed

_STRUCTURE = re.compile(rb'[\[\]{}"\\]')
_OPEN, _CLOSE = frozenset(b"[{"), frozenset(b"]}")
_QUOTE, _BACKSLASH = ord('"'), ord("\\")


def nested_deeper_than(body: bytes, limit: int) -> bool:
    """Whether the JSON text ``body`` opens more than ``limit`` arrays or objects inside
    each other. Malformed JSON is not judged here (the parser refuses it afterwards)."""
    if body.count(b"[") + body.count(b"{") <= limit:
        return False
    depth, in_string, escaped = 0, False, -1
    for match in _STRUCTURE.finditer(body):
        position, byte = match.start(), body[match.start()]
        if in_string:
            if position == escaped:         # the character after a backslash
                continue
            if byte == _BACKSLASH:
                escaped = position + 1
            elif byte == _QUOTE:
                in_string = False
        elif byte == _QUOTE:
            in_string = True
        elif byte in _OPEN:
            depth += 1
            if depth > limit:
                return True
        elif byte in _CLOSE:
            depth -= 1
    return False


def too_deep_message() -> str:
    return f"nested deeper than {MAX_DEPTH} levels (arrays and objects inside each other)"


class JsonDepthLimit:
    """ASGI middleware: a request body nested deeper than ``MAX_DEPTH`` is answered
    422 before the app reads it. The body is read whole (it sits inside the body size
    limit's middleware, so at most ``max_body_bytes``) and handed on unchanged.
    ``exempt``: (method, path) of routes that read and check their bodies themselves
    (the scene upload streams its own, larger body)."""

    def __init__(self, app: ASGIApp, exempt: tuple[tuple[str, str], ...] = ()) -> None:
        self.app, self.exempt = app, exempt

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if (scope["type"] != "http" or scope["method"] in ("GET", "HEAD", "OPTIONS")
                or (scope["method"], scope["path"]) in self.exempt):
            await self.app(scope, receive, send)
            return
        chunks, message = [], await receive()
        while message["type"] == "http.request":
            chunks.append(message.get("body", b""))
            if not message.get("more_body", False):
                break
            message = await receive()
        body = b"".join(chunks)
        if nested_deeper_than(body, MAX_DEPTH):
            error = unprocessable(too_deep_message(), type="too_deep")
            response = await validation_failed(Request(scope), error)
            await response(scope, receive, send)
            return
        pending: list[Message] = [{"type": "http.request", "body": body, "more_body": False}
                                  if message["type"] == "http.request" else message]

        async def replay() -> Message:
            return pending.pop() if pending else await receive()

        await self.app(scope, replay, send)
