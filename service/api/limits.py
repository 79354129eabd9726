"""Bounds on what one request may make the service hold, store or send back.

* The body: at most ``max_body_bytes`` of service/config.py (413 naming the limit).
  A declared Content-Length over the limit is refused before anything is read; a body sent
  without one (chunked) is counted as it streams in and refused when it passes the
  limit, so a client cannot make the service buffer more than the limit.
* Nesting: no body may nest arrays and objects deeper than ``MAX_DEPTH``, checked on
  the bytes before any parser recurses into them (service/api/nesting.py; 422).
* Free-form JSON inside an accepted body (``params`` is a dict of anything): string
  and list lengths and the total size of ``params`` are capped (422 naming the
  field), so a spec that is stored and served to every reader stays small.
* Text: JSON may spell a lone UTF-16 surrogate (``"\\ud800"``), which is no Unicode
  character: it cannot be stored, hashed or sent back as UTF-8, so a string or key
  holding one is refused (422) before anything uses it.
* Echoes: a 422 repeats the offending input, cut to a few hundred characters.
"""

from __future__ import annotations

import json
from typing import Any

from fastapi import HTTPException, Request, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

#: Longest string anywhere in a JSON body (a scene path is far shorter; PATH_MAX is 4096).
MAX_STRING_CHARS = 4096
#: Longest list anywhere in a JSON body (sweep axes, N_c per vertex, ...).
MAX_LIST_ITEMS = 1000
#: Most keys of one JSON object.
MAX_OBJECT_KEYS = 200
#: Deepest nesting of a JSON body (spec → params → cache → a value is 4).
MAX_DEPTH = 10
#: Largest ``params`` of a spec, as compact JSON.
MAX_PARAMS_BYTES = 16_384
#: Characters of an offending input that a 422 repeats; of any other text in it.
ECHO_INPUT_CHARS = 200
ECHO_TEXT_CHARS = 1000


class _BodyTooLarge(HTTPException):
    def __init__(self, limit: int) -> None:
        super().__init__(status.HTTP_413_CONTENT_TOO_LARGE,
                         f"request body larger than {limit} bytes, this service's limit "
                         "(NIRC_BENCH_MAX_BODY_BYTES)")


class BodySizeLimit:
    """ASGI middleware: 413 for a body over ``max_bytes``, without buffering it.

    ``exempt``: (method, path) of routes that enforce a limit of their own (a
    scene upload carries its files and has its own, larger cap).
    """

    def __init__(self, app: ASGIApp, max_bytes: int,
                 exempt: tuple[tuple[str, str], ...] = ()) -> None:
        self.app, self.max_bytes, self.exempt = app, max_bytes, exempt

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or (scope["method"], scope["path"]) in self.exempt:
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and (not declared.isdigit() or int(declared) > self.max_bytes):
            await self._refuse(send, _BodyTooLarge(self.max_bytes) if declared.isdigit() else
                               HTTPException(status.HTTP_400_BAD_REQUEST,
                                             "Content-Length is not a number"))
            return
        received = 0
        started = False

        async def counting_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise _BodyTooLarge(self.max_bytes)
            return message

        async def watching_send(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counting_receive, watching_send)
        except _BodyTooLarge as err:
            # Normally answered by the app's HTTPException handler; this covers a read
            # outside a route (e.g. another middleware).
            if started:
                raise
            await self._refuse(send, err)

    @staticmethod
    async def _refuse(send: Send, err: HTTPException) -> None:
        response = JSONResponse({"detail": err.detail}, status_code=err.status_code,
                                headers={"Connection": "close"})
        await response({"type": "http"}, _no_body, send)


async def _no_body() -> Message:
    return {"type": "http.disconnect"}


def _violation(path: list[Any], value: Any, kind: str, message: str) -> dict[str, Any]:
    return {"loc": ["body", *map(_printable, path)], "msg": message, "type": kind,
            "input": _printable(value)}


def _printable(value: Any) -> Any:
    """``value`` with any lone surrogate spelled as its escape (``\\ud800``), so that
    the answer that echoes it can be encoded."""
    if isinstance(value, str) and not is_unicode(value):
        return value.encode("utf-8", "backslashreplace").decode("utf-8")
    return value


def is_unicode(text: str) -> bool:
    """False for text holding a lone surrogate (JSON's ``\\ud800``), which UTF-8
    cannot encode."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


_NOT_UNICODE = "holds a lone UTF-16 surrogate (such as \\ud800), which is not Unicode text"


def _shape_errors(value: Any, path: list[Any]) -> list[dict[str, Any]]:
    """Where ``value`` (parsed JSON, nested at most ``MAX_DEPTH`` deep: service/api/nesting.py)
    passes the string, list and key limits."""
    if isinstance(value, str):
        if not is_unicode(value):
            return [_violation(path, value, "string_unicode", f"a string that {_NOT_UNICODE}")]
        if len(value) > MAX_STRING_CHARS:
            return [_violation(path, value, "string_too_long",
                               f"a string of {len(value)} characters: at most "
                               f"{MAX_STRING_CHARS} are accepted")]
        return []
    if not isinstance(value, dict | list):
        return []
    if isinstance(value, list):
        if len(value) > MAX_LIST_ITEMS:
            return [_violation(path, value, "too_long",
                               f"a list of {len(value)} items: at most {MAX_LIST_ITEMS} "
                               "are accepted")]
        items = enumerate(value)
    else:
        if len(value) > MAX_OBJECT_KEYS:
            return [_violation(path, value, "too_long",
                               f"an object of {len(value)} keys: at most {MAX_OBJECT_KEYS} "
                               "are accepted")]
        items = value.items()
    errors = []
    for key, item in items:
        if isinstance(key, str) and len(key) > MAX_STRING_CHARS:
            return [_violation(path, key, "string_too_long", "a key too long")]
        if isinstance(key, str) and not is_unicode(key):
            return [_violation(path, key, "string_unicode", f"a key that {_NOT_UNICODE}")]
        errors += _shape_errors(item, [*path, key])
        if errors:          # the first few are enough to fix the request
            return errors
    return errors


def body_shape_errors(body: Any) -> list[dict[str, Any]]:
    """Errors (FastAPI's 422 format) of a parsed JSON body over this module's limits."""
    errors = _shape_errors(body, [])
    if errors or not isinstance(body, dict) or not isinstance(body.get("params"), dict):
        return errors
    size = len(json.dumps(body["params"], separators=(",", ":")))
    if size > MAX_PARAMS_BYTES:
        return [_violation(["params"], body["params"], "too_long",
                           f"params of {size} bytes as JSON: at most {MAX_PARAMS_BYTES} "
                           "are accepted")]
    return []


async def bounded_json_body(request: Request) -> None:
    """Dependency of the routers: a JSON body within the limits above, else 422 (before
    the spec is validated, so that no message built from it repeats a huge value)."""
    if request.method in ("GET", "HEAD", "OPTIONS"):
        return
    if not await request.body():
        return
    try:
        body = await request.json()
    except ValueError:
        return      # not JSON: FastAPI's own validation answers it
    errors = body_shape_errors(body)
    if errors:
        raise RequestValidationError(errors)


def _cut(text: str, limit: int) -> str:
    return text if len(text) <= limit else f"{text[:limit]}… ({len(text)} characters, cut)"


def truncate_echo(error: dict[str, Any]) -> dict[str, Any]:
    """A 422 error with its echoed ``input`` (and any long text) cut short."""
    out = {}
    for key, value in error.items():
        if key == "input" and not (value is None or isinstance(value, bool | int | float)):
            text = value if isinstance(value, str) else json.dumps(value, default=str)
            out[key] = value if len(text) <= ECHO_INPUT_CHARS else _cut(text, ECHO_INPUT_CHARS)
        elif isinstance(value, str):
            out[key] = _cut(value, ECHO_TEXT_CHARS)
        elif key == "ctx" and isinstance(value, dict):
            out[key] = {k: _cut(v, ECHO_TEXT_CHARS) if isinstance(v, str) else v
                        for k, v in value.items()}
        else:
            out[key] = value
    return out
