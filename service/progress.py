"""Progress of long work (reference, seed k/K, sweep stages), in any output.

On a terminal: rich bars, one per stage, started at the first report (so a command that
fails before any work prints no empty display). Anywhere else (a log, a pipe, CI): plain
lines on standard error, one when a stage starts, one when it finishes and at most one
every :data:`PLAIN_INTERVAL_S` seconds in between, so that standard output keeps only
the result.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

Reporter = Callable[[str, int, int], None]

#: Seconds between two plain progress lines of one unfinished stage.
PLAIN_INTERVAL_S = 10.0


class PlainProgress:
    """report(stage, done, total) as plain lines 'progress: <stage> <done>/<total> (<s> s)'."""

    def __init__(self, console: Console, interval_s: float = PLAIN_INTERVAL_S) -> None:
        self.console = console
        self.interval_s = interval_s
        self.started = time.monotonic()
        self.last: dict[str, float] = {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        now = time.monotonic()
        new, finished = stage not in self.last, done >= total
        if not (new or finished or now - self.last[stage] >= self.interval_s):
            return
        if finished and self.last.get(stage) == float("inf"):
            return      # said already
        self.last[stage] = float("inf") if finished else now
        self.console.print(f"progress: {stage} {done}/{total} ({now - self.started:.0f} s)",
                           markup=False, highlight=False, emoji=False, soft_wrap=True)


@contextmanager
def progress_reporter(console: Console, quiet: bool = False,
                      plain_console: Console | None = None) -> Iterator[Reporter]:
    """Yield report(stage, done, total): bars on a terminal ``console``, else plain lines
    on ``plain_console`` (standard error by default); nothing when ``quiet``."""
    if quiet:
        yield lambda stage, done, total: None
        return
    if not console.is_terminal:
        yield PlainProgress(plain_console or Console(stderr=True, emoji=False))
        return
    columns = (TextColumn("{task.description:>12}"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn(), TimeRemainingColumn())
    bars = Progress(*columns, console=console, transient=False)
    tasks: dict[str, int] = {}

    def report(stage: str, done: int, total: int) -> None:
        if not tasks:
            bars.start()
        if stage not in tasks:
            tasks[stage] = bars.add_task(stage, total=total)
        bars.update(tasks[stage], completed=done, total=total)

    try:
        yield report
    finally:
        if tasks:
            bars.stop()
