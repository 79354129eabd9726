"""Slow clients against a real `nirc-bench serve`: a connection that trickles its
request's headers (or sends nothing) is answered 408 and closed after the header
deadline, one that trickles its body below the minimum rate is closed after a body
window; a body sent just above that rate over several windows is answered.

The deadlines are set short in the service's environment (1 s, 1 s windows, 200 B/s)
so each case takes a second or two; the defaults are 10 s, 10 s and 1000 B/s. Before
the deadlines a trickling connection stayed open as long as it kept trickling (here:
until the test's own limit)."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import pytest

from tests.service.live import Service

HEADER_TIMEOUT_S = 1.0
BODY_WINDOW_S = 1.0
BODY_MIN_BYTES_PER_S = 200.0
#: How long a test keeps trickling before it calls the connection never cut.
GIVE_UP_S = 8.0


@pytest.fixture(scope="module")
def service(tmp_path_factory) -> Iterator[Service]:
    service = Service(tmp_path_factory.mktemp("slow") / "data")
    service.env.update({"NIRC_BENCH_HEADER_TIMEOUT_S": str(HEADER_TIMEOUT_S),
                        "NIRC_BENCH_BODY_WINDOW_S": str(BODY_WINDOW_S),
                        "NIRC_BENCH_BODY_MIN_BYTES_PER_S": str(BODY_MIN_BYTES_PER_S)})
    service.start()
    yield service
    service.stop()


def _trickle(service: Service, head: bytes, pieces: Iterator[bytes],
             interval_s: float) -> tuple[float, bytes]:
    """Send ``head``, then one of ``pieces`` every ``interval_s`` until the service
    closes the connection or ``pieces`` run out; returns the seconds from the first
    byte until it closed (inf if it did not) and what the service answered."""
    with socket.create_connection(("127.0.0.1", service.port), timeout=GIVE_UP_S) as sock:
        start = time.monotonic()
        sock.sendall(head)
        sock.settimeout(interval_s)
        answer = b""
        for piece in pieces:
            try:
                chunk = sock.recv(65536)
            except TimeoutError:        # nothing yet: keep sending
                try:
                    sock.sendall(piece)
                except OSError:         # closed while we sent
                    return time.monotonic() - start, answer
                continue
            except ConnectionResetError:
                return time.monotonic() - start, answer
            answer += chunk
            if not chunk:
                return time.monotonic() - start, answer
        return float("inf"), answer


def _for(seconds: float, piece: bytes, interval_s: float) -> Iterator[bytes]:
    return iter([piece] * int(seconds / interval_s))


def _post_head(length: int) -> bytes:
    return (b"POST /api/v1/auth/login HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            b"Content-Type: application/json\r\nConnection: close\r\n"
            b"Content-Length: %d\r\n\r\n" % length)


@pytest.mark.parametrize("head", [b"GET /api/v1/scenes HTTP/1.1\r\nHost: 127.0.0.1\r\n", b""],
                         ids=["trickled-headers", "nothing-sent"])
def test_a_request_whose_headers_come_too_slowly_is_closed_after_the_deadline(service, head):
    """Answered 408 if part of a request came, closed without an answer if nothing."""
    piece = b"X-Pad: a\r\n" if head else b""
    closed_after_s, answer = _trickle(service, head, _for(GIVE_UP_S, piece, 0.25), 0.25)
    assert HEADER_TIMEOUT_S * 0.9 <= closed_after_s <= HEADER_TIMEOUT_S + 3.0, closed_after_s
    assert answer.startswith(b"HTTP/1.1 408 ") if head else answer == b"", answer


def test_a_body_below_the_minimum_rate_is_cut_after_a_window(service):
    # 10 bytes every 0.25 s: 40 B/s, a fifth of the minimum.
    closed_after_s, answer = _trickle(service, _post_head(4000),
                                      _for(GIVE_UP_S, b" " * 10, 0.25), 0.25)
    assert BODY_WINDOW_S * 0.9 <= closed_after_s <= BODY_WINDOW_S + 3.0, closed_after_s
    assert answer == b""


def test_a_body_just_above_the_minimum_rate_is_answered_after_several_windows(service):
    """The control: the deadline is on the rate, not on the body's time (2.5 windows)."""
    body = b'{"api_key": "not-a-key"}'.ljust(1500)     # 600 B/s: 150 bytes every 0.25 s
    pieces = iter([body[i:i + 150] for i in range(0, len(body), 150)] + [b""] * 20)
    closed_after_s, answer = _trickle(service, _post_head(len(body)), pieces, 0.25)
    assert answer.startswith(b"HTTP/1.1 403 "), answer
