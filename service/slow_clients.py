"""Deadlines on what a client sends: a connection that trickles its request is cut.

uvicorn bounds only the idle time between requests (``timeout_keep_alive``); a
connection may take forever to send a request's headers (or send nothing at all),
and a request's body may arrive a byte at a time, each holding a connection and its
buffers open (slow-loris). ASGI middleware cannot help: it runs once the headers are
parsed. So ``nirc-bench serve`` runs uvicorn's h11 protocol with two deadlines added,
watched from h11's state of the client's side of the connection:

* **headers** (h11 ``IDLE``): a request's headers must be complete within
  ``header_timeout_s`` of the connection's opening, or of the end of the previous
  response on a kept-alive connection; after that the connection is closed, answered
  ``408 Request Timeout`` first if part of a request had come (an idle connection is
  closed without an answer, as uvicorn closes idle kept-alive ones).
* **body** (h11 ``SEND_BODY``): while the service waits for a body, each window of
  ``body_window_s`` must bring at least ``body_min_bytes_per_s`` on average, else the
  connection is closed (the route sees the client leave). A window in which the
  service stopped reading (its buffer full: the route is slow to take the body, not
  the client to send it) or has not yet asked for a body sent after
  ``Expect: 100-continue`` is not held against the client.

While the route works on a complete request, nothing is timed here (a long poll
may take its time).

The same protocol bounds the connections open at once (``max_connections``): while
more are open, a request on any of them is answered 503 in JSON with ``Retry-After``
and its connection closed (as uvicorn's own ``limit_concurrency`` does, whose answer
is plain text without the security headers).
"""

from __future__ import annotations

import asyncio
import json
import logging
from dataclasses import dataclass
from typing import Literal

import h11
from starlette.types import Receive, Scope, Send
from uvicorn.protocols.http.h11_impl import H11Protocol

from service.api.headers import security_headers

log = logging.getLogger(__name__)

Phase = Literal["headers", "body"]

#: The answer to a connection whose headers came too slowly (its request unknown).
REQUEST_TIMEOUT = (b"HTTP/1.1 408 Request Timeout\r\ncontent-type: text/plain; charset=utf-8\r\n"
                   b"connection: close\r\ncontent-length: %d\r\n\r\n%s")


@dataclass(frozen=True)
class ClientDeadlines:
    """How slowly a client may send (service/config.py has the settings)."""

    header_timeout_s: float
    body_window_s: float
    body_min_bytes_per_s: float

    def protocol(self, max_connections: int | None = None) -> type[H11Protocol]:
        """uvicorn's h11 protocol with these deadlines (uvicorn's ``http=``), serving at
        most ``max_connections`` connections at once (None: any number)."""
        return type("DeadlineH11Protocol", (DeadlineH11Protocol,),
                    {"deadlines": self, "max_connections": max_connections})


#: Seconds a client refused for too many connections is asked to wait.
BUSY_RETRY_AFTER_S = 1


async def too_many_connections(scope: Scope, receive: Receive, send: Send) -> None:
    """The answer to a request while more connections are open than are served."""
    body = json.dumps({"detail": "the service has more connections open than it serves at "
                                 "once (max_connections); try again shortly"}).encode()
    await send({"type": "http.response.start", "status": 503, "headers": [
        (b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
        (b"retry-after", str(BUSY_RETRY_AFTER_S).encode()), (b"connection", b"close"),
        *security_headers(scope["path"])]})
    await send({"type": "http.response.body", "body": body})


class DeadlineH11Protocol(H11Protocol):
    """uvicorn's h11 protocol that cuts connections sending too slowly (module doc);
    made with its deadlines by :meth:`ClientDeadlines.protocol`."""

    deadlines: ClientDeadlines
    max_connections: int | None = None
    _timer: asyncio.TimerHandle | None = None
    _phase: Phase | None = None
    _bytes = 0      # received in this phase (headers), or this window (body)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:  # type: ignore[override]
        super().connection_made(transport)  # type: ignore[arg-type]
        self._watch()

    def data_received(self, data: bytes) -> None:
        self._bytes += len(data)
        super().data_received(data)
        self._watch()

    def handle_events(self) -> None:
        # The connections open now include this one; past the limit its request (each
        # request of it while the limit is passed) gets the 503.
        busy = self.max_connections is not None and len(self.connections) > self.max_connections
        self.app = too_many_connections if busy else self.config.loaded_app
        super().handle_events()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._watch()

    def connection_lost(self, exc: Exception | None) -> None:
        self._stop_timer()
        super().connection_lost(exc)

    def _client_phase(self) -> Phase | None:
        """What the service waits for from the client, None when nothing."""
        if self.transport.is_closing():
            return None
        state = self.conn.their_state
        if state is h11.IDLE:
            return "headers"
        return "body" if state is h11.SEND_BODY else None

    def _watch(self) -> None:
        """Start the deadline of the phase the connection is in, once per phase."""
        phase = self._client_phase()
        if phase == self._phase:
            return
        self._stop_timer()
        self._phase = phase
        self._bytes = 0
        if phase == "headers":
            self._timer = self.loop.call_later(self.deadlines.header_timeout_s,
                                               self._headers_late)
        elif phase == "body":
            self._start_body_window()

    def _stop_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _start_body_window(self) -> None:
        self._bytes = 0
        self._timer = self.loop.call_later(self.deadlines.body_window_s, self._body_window_end)

    def _headers_late(self) -> None:
        self._timer = None
        if not self._bytes:     # idle, not slow
            self.transport.close()
            return
        message = (f"the request's headers did not arrive within "
                   f"{self.deadlines.header_timeout_s:g} s\n").encode()
        self._cut("headers", REQUEST_TIMEOUT % (len(message), message))

    def _body_window_end(self) -> None:
        self._timer = None
        deadlines = self.deadlines
        needed = deadlines.body_min_bytes_per_s * deadlines.body_window_s
        waiting_for_route = self.flow.read_paused or (
            self.cycle is not None and self.cycle.waiting_for_100_continue)
        if self._bytes < needed and not waiting_for_route:
            self._cut("body", b"")
        else:
            self._start_body_window()

    def _cut(self, phase: Phase, answer: bytes) -> None:
        client = "{}:{}".format(*self.client) if self.client else "client"
        log.warning("%s - connection cut: its request's %s came too slowly", client, phase)
        if answer:
            self.transport.write(answer)
        self.transport.close()
