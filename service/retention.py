"""Retention on its own: the service applies `nirc-bench gc`'s plan on a timer.

Every ``retention_interval_h`` hours (the first round one interval after the service
starts; None or 0: never) a thread plans and applies the retention of
jobs/record/gc.py with the service's settings — unreferenced files, scenes and
references older than ``gc_keep_days``, the artifacts of runs and sweeps and the
reproduced figures past ``artifact_keep_days`` or ``artifact_max_bytes``, runs the
user named or tagged and the reproductions of queued or running jobs kept — and logs each thing it removed and what the round freed, on the server's
log (uvicorn's). A round that fails is logged; the next one tries again.
"""

from __future__ import annotations

import logging
import threading

from jobs.record import gc
from jobs.record.config import Settings
from jobs.record.store import Store

#: A child of uvicorn's error log, so that its lines reach the server's output.
log = logging.getLogger("uvicorn.error.retention")

SECONDS_PER_HOUR = 3600.0


def retention_round(store: Store, settings: Settings) -> gc.Plan:
    """Plan and apply the retention once; returns what it removed (each logged)."""
    plan = gc.plan(store, settings)
    if not plan.removals:
        return plan
    freed = gc.apply(store, settings, plan)
    for removal in plan.removals:
        log.info("retention removed %s %s (%d bytes)", removal.what, removal.name,
                 removal.bytes)
    log.info("retention removed %d items, %d bytes", len(plan.removals), freed)
    return plan


def start_retention(store: Store, settings: Settings) -> threading.Event | None:
    """The retention thread (daemon), or None when it is off; set the event to stop it."""
    if settings.retention_interval_h is None:
        return None
    interval_s = settings.retention_interval_h * SECONDS_PER_HOUR
    stop = threading.Event()

    def rounds() -> None:
        while not stop.wait(interval_s):
            try:
                retention_round(store, settings)
            except Exception:  # noqa: BLE001 - logged; the next round tries again
                log.exception("a retention round failed")

    threading.Thread(target=rounds, name="nirc-bench-retention", daemon=True).start()
    return stop
