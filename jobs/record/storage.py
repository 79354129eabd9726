"""What a failed write to the data folder or the database means for the service.

Two kinds of storage failure are expected in operation and are not bugs:

* **full**: no space (``ENOSPC``), a quota (``EDQUOT``), a file size limit
  (``EFBIG``, e.g. ``RLIMIT_FSIZE``) or an I/O error (``EIO``: an image that did not
  read back as written, metrics/imageio.py) stopped a write of a file, or the database
  could not write (SQLite ``SQLITE_FULL`` or an I/O error while writing;
  PostgreSQL's class 53, insufficient resources). Nothing is wrong with the request:
  the service cannot store what it needs (HTTP 507). A check of our own that finds a
  file shorter than what was written raises :class:`StorageFull` too.
* **unavailable**: the database is locked past the lock timeout, a statement was
  canceled by it, or the connection was lost (HTTP 503, try again).

:func:`storage_failure` tells which (None: neither). The API answers these in JSON,
the runner keeps a job that met one recoverable (jobs/execution/runner.py).
"""

from __future__ import annotations

import errno
import sqlite3
from typing import Literal

from sqlalchemy.exc import DBAPIError
from sqlalchemy.exc import TimeoutError as PoolTimeout

FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO})
#: SQLite's primary result codes (the low byte of an extended code).
_SQLITE_FULL, _SQLITE_IOERR, _SQLITE_BUSY, _SQLITE_LOCKED = 13, 10, 5, 6

Failure = Literal["full", "unavailable"]


class StorageFull(OSError):
    """A write that reported success left less than it was given (checked by reading
    the file back): treated like a full disk."""

    def __init__(self, message: str) -> None:
        super().__init__(errno.ENOSPC, message)


def storage_failure(err: BaseException) -> Failure | None:
    """'full', 'unavailable' or None for an exception (see the module doc)."""
    if isinstance(err, OSError):
        return "full" if err.errno in FULL_ERRNOS else None
    if isinstance(err, PoolTimeout):
        return "unavailable"
    if not isinstance(err, DBAPIError):
        return None
    if err.connection_invalidated:
        return "unavailable"
    original = err.orig
    if isinstance(original, sqlite3.Error):
        code = (getattr(original, "sqlite_errorcode", 0) or 0) & 0xFF
        if code in (_SQLITE_FULL, _SQLITE_IOERR):
            return "full"
        if code in (_SQLITE_BUSY, _SQLITE_LOCKED):
            return "unavailable"
        return None
    state = getattr(original, "sqlstate", None) or ""
    if state.startswith("53"):                       # disk_full, out_of_memory, ...
        return "full"
    # lock_not_available, query_canceled (lock or statement timeout), connection
    # exceptions, the server shutting down.
    if state in ("55P03", "57014") or state.startswith(("08", "57P")):
        return "unavailable"
    return None


def describe(err: BaseException) -> str:
    """One line naming the storage failure and its cause, for a job's error or an
    answer (never a traceback)."""
    kind = storage_failure(err)
    cause = err.strerror if isinstance(err, OSError) and err.strerror else str(
        getattr(err, "orig", None) or err).strip().splitlines()[0]
    where = f" ({err.filename})" if isinstance(err, OSError) and err.filename else ""
    if kind == "full":
        return f"storage full: the service could not write its data{where}: {cause}"
    if kind == "unavailable":
        return f"database unavailable: {cause}"
    return f"{type(err).__name__}: {cause}"
