"""The marker a running reproduction holds in its folder, so that retention
(jobs/record/gc.py) leaves the folder alone while it is written.

``nirc-bench reproduce`` run from the command line is no job of the service: no row
says it is running. While it runs (measure, table, PNG, provenance) its folder holds
``.running.json`` with the process's id, host and start time; the marker is removed
when the run ends, also when it fails. A marker protects its folder while its process
lives: same host, that pid alive and started no later than the marker (a pid reused by a
later process does not count). A marker whose process is gone (killed, or the machine
restarted) or was written on another host (its pid cannot be checked here) protects
nothing: the folder counts as an unfinished reproduction, removed once its newest file
is older than ``gc_keep_days``. The marker is also a lock: a second run into a folder
whose marker's process lives (or was written on another host) is refused
(:class:`FolderBusy`) instead of mixing its files with the first's.
"""

from __future__ import annotations

import json
import os
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import psutil

MARKER = ".running.json"
#: Slack between a process's recorded start and its marker's time (clock rounding).
START_SLACK_S = 1.0


class FolderBusy(Exception):
    """A reproduction's folder that another live process is writing."""


@dataclass(frozen=True)
class Holder:
    """The process a marker names."""

    pid: int
    host: str
    started_at: datetime

    def alive(self) -> bool:
        """Whether the process that wrote the marker still runs (on this host)."""
        if self.host != socket.gethostname():
            return False
        try:
            process = psutil.Process(self.pid)
            if process.status() == psutil.STATUS_ZOMBIE:
                return False
            return process.create_time() <= self.started_at.timestamp() + START_SLACK_S
        except (psutil.NoSuchProcess, psutil.ZombieProcess):
            return False
        except psutil.AccessDenied:     # another user's process: it exists
            return True


def holder(folder: Path) -> Holder | None:
    """The process ``folder``'s marker names, None without a (readable) marker."""
    try:
        fields = json.loads((folder / MARKER).read_text())
        started = datetime.fromisoformat(fields["started_at"])
        return Holder(int(fields["pid"]), str(fields["host"]),
                      started if started.tzinfo else started.replace(tzinfo=UTC))
    except (OSError, ValueError, KeyError, TypeError):
        return None     # none, or unreadable


def is_running(folder: Path) -> bool:
    """Whether a live process holds ``folder``'s marker."""
    found = holder(folder)
    return found is not None and found.alive()


@contextmanager
def running_marker(folder: Path) -> Iterator[None]:
    """Hold ``folder``'s marker (the folder is made if missing) for the ``with`` body;
    FolderBusy if a live process holds it, or one on another host (it cannot be checked
    from here). The marker goes at the end, whatever the end, and so does the folder if
    it was made here and nothing else was written in it."""
    made = not folder.exists()
    folder.mkdir(parents=True, exist_ok=True)
    marker = folder / MARKER
    # Written whole beside it, then linked in: a reader never sees a partial marker, and
    # the link fails if another process's marker is there.
    draft = folder / f"{MARKER}.{os.getpid()}"
    draft.write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                                 "started_at": datetime.now(UTC).isoformat()}))
    try:
        _take(marker, draft)
    finally:
        draft.unlink(missing_ok=True)
    try:
        yield
    finally:
        marker.unlink(missing_ok=True)
        if made:
            try:
                folder.rmdir()
            except OSError:
                pass        # files of this run or of others: kept


def _take(marker: Path, draft: Path) -> None:
    """Link ``draft`` as ``marker``, replacing a stale one; FolderBusy otherwise."""
    for _attempt in range(2):
        try:
            os.link(draft, marker)
            return
        except FileExistsError:
            found = holder(marker.parent)
            if found is not None and (found.host != socket.gethostname() or found.alive()):
                raise FolderBusy(
                    f"{marker.parent} is being written by another reproduction (process "
                    f"{found.pid} on {found.host}, since {found.started_at:%Y-%m-%d %H:%M} "
                    f"UTC): wait for it, give another folder with --out, or remove {marker} "
                    "if that process is gone") from None
            marker.unlink(missing_ok=True)      # stale: its process is gone
    raise FolderBusy(f"{marker.parent}: another reproduction took its marker at the same time")
