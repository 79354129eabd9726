"""Room for new work: the data folder's free-space floor and each API key's quota.

Both answer 507 with a JSON body that says which limit, its setting and the numbers
(:class:`NoRoom`), before anything is queued or stored:

* **Free-space floor**: new jobs, sweeps and uploads are refused while the data
  folder's filesystem has less free than ``max(min_free_bytes, min_free_fraction x
  its size)`` (``shutil.disk_usage``): the space left is for the jobs already
  accepted, the database and the results they write.
* **Per-key quota** (``key_quota_bytes``): what a key holds
  (jobs/record/usage.py: its runs' and sweeps' artifacts, its uploads) plus the
  estimated files of its queued and running jobs (``artifact_bytes`` of
  jobs/execution/work.py, the estimate of the data folder's cap ``max_data_bytes``)
  plus the request's own estimate must stay within it. The usage is one query on
  the store and a walk of the key's own upload folders; a job's estimate depends on
  its spec alone and is kept per spec key (:func:`queued_bytes`), so each queued
  job's spec is read and estimated once per process.
"""

from __future__ import annotations

import logging
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request, status
from fastapi.responses import JSONResponse

from jobs.execution.queued import job_of
from jobs.record.config import Settings
from jobs.record.store import Store
from jobs.record.usage import jobs_with_spec_keys, stored_bytes, unfinished_spec_keys

log = logging.getLogger(__name__)

GIB = 2**30


class NoRoom(Exception):
    """New work refused for want of room: 507 with ``detail`` and the numbers."""

    def __init__(self, detail: str, **numbers: Any) -> None:
        super().__init__(detail)
        self.detail, self.numbers = detail, numbers


async def no_room(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, NoRoom)
    return JSONResponse({"detail": exc.detail, **exc.numbers},
                        status_code=status.HTTP_507_INSUFFICIENT_STORAGE)


def add_no_room_handler(app: FastAPI) -> None:
    app.add_exception_handler(NoRoom, no_room)


def _existing(path: Path) -> Path:
    """``path`` or its nearest existing parent (the filesystem it will be on)."""
    while not path.exists() and path.parent != path:
        path = path.parent
    return path


def readable_size(n_bytes: float) -> str:
    """``n_bytes`` with three significant digits in the largest binary unit that keeps
    it at least 1 (a tiny quota reads '48.8 KiB', not '0.000 GiB')."""
    for unit, scale in (("GiB", GIB), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if abs(n_bytes) >= scale:
            return f"{n_bytes / scale:.3g} {unit}"
    return f"{int(n_bytes)} B"


def check_free_space(settings: Settings) -> None:
    """507 while the data folder's filesystem has less free than the floor."""
    usage = shutil.disk_usage(_existing(settings.data_dir))
    floor = max(settings.min_free_bytes, settings.min_free_fraction * usage.total)
    if usage.free < floor:
        raise NoRoom(
            f"the data folder's disk has {readable_size(usage.free)} free, under this "
            f"service's floor of {readable_size(floor)} (the larger of min_free_bytes, "
            f"{readable_size(settings.min_free_bytes)}, and min_free_fraction, "
            f"{settings.min_free_fraction:.0%} of {readable_size(usage.total)}): no new work "
            "until space is freed (`nirc-bench gc --apply`)",
            limit="min_free_bytes", free_bytes=usage.free, floor_bytes=int(floor))


#: The estimated files of each spec key seen (a job's estimate depends on its spec
#: alone, and a spec key is a digest of its kind and spec), bounded: cleared when full.
_ESTIMATES: dict[str, int] = {}
_MAX_ESTIMATES = 4096


def _estimated_bytes(job: Any) -> int:
    """The files a queued job may write: its whole work's ``artifact_bytes`` (a render's
    reference counted, a sweep's every stage)."""
    try:
        return job_of(job).work().artifact_bytes
    except ValueError as err:       # a spec today's parser refuses: it will not run
        log.warning("job of spec key %s cannot be estimated: %s", job.spec_key, err)
        return 0


def queued_bytes(store: Store, key_id: int) -> int:
    """The estimated files of key ``key_id``'s unfinished jobs: their spec keys are
    read, and a spec only for keys not estimated before (a submission reads no spec
    of the jobs queued before it)."""
    spec_keys = unfinished_spec_keys(store, key_id)
    unknown = set(spec_keys).difference(_ESTIMATES)
    if unknown:
        if len(_ESTIMATES) + len(unknown) > _MAX_ESTIMATES:
            _ESTIMATES.clear()
        for job in jobs_with_spec_keys(store, unknown):
            _ESTIMATES[job.spec_key] = _estimated_bytes(job)
    return sum(_ESTIMATES.get(key, 0) for key in spec_keys)


@dataclass(frozen=True)
class KeyUsage:
    stored_bytes: int       # its results' artifacts and its uploads, on disk
    queued_bytes: int       # the estimated files of its queued and running jobs

    @property
    def bytes(self) -> int:
        return self.stored_bytes + self.queued_bytes


def key_usage(store: Store, settings: Settings, key_id: int) -> KeyUsage:
    return KeyUsage(stored_bytes(store, settings, key_id), queued_bytes(store, key_id))


def check_room(store: Store, settings: Settings, key_id: int, request_bytes: int,
               what: str) -> None:
    """507 (:class:`NoRoom`) when the disk is under its free-space floor, or when key
    ``key_id``'s usage plus ``request_bytes`` (the estimate of ``what``: 'render job',
    'scene upload', ...) is over its quota."""
    check_free_space(settings)
    quota = settings.key_quota_bytes
    if quota is None:
        return
    usage = key_usage(store, settings, key_id)
    if usage.bytes + request_bytes > quota:
        raise NoRoom(
            f"this {what} may write {readable_size(request_bytes)}; this API key holds "
            f"{readable_size(usage.bytes)} ({readable_size(usage.stored_bytes)} stored, "
            f"{readable_size(usage.queued_bytes)} estimated for its unfinished jobs) of its "
            f"quota of {readable_size(quota)} (key_quota_bytes): cancel unfinished jobs, or "
            "ask the operator to free space (`nirc-bench gc`, artifact_keep_days)",
            limit="key_quota_bytes", quota_bytes=quota, used_bytes=usage.bytes,
            stored_bytes=usage.stored_bytes, queued_bytes=usage.queued_bytes,
            request_bytes=request_bytes)
