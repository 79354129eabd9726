"""The reproduced papers' figures in the data folder, as retention sees them
(jobs/record/gc.py): the layout jobs/reproduce writes, read without importing it.

``<data>/reproduce/<paper>-<figure>/`` holds the CLI's reproduction of a figure (its own
files: ``table.json``, ``table.md``, ``figure.png`` and what the figure draws beside,
``provenance.json`` written last) and each service job's in ``job-<id>/``. A
reproduction finished when its ``provenance.json`` says (``finished_at``); one without
(stored before provenance was recorded, or whose drawing failed) is dated by its
``table.json``; one without a table never finished (it is written after the figure's
measure). A folder whose run is under way holds its marker (jobs/record/reproduction_marker.py):
while its process lives the reproduction is ``running``; a marker left by a process that
is gone says the run never finished, whatever older files the folder holds.

Their bytes count in the data folder's size (``max_data_bytes``) and a job's in its
key's quota (jobs/record/usage.py): :func:`reproduction_bytes`.
"""

from __future__ import annotations

import json
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from jobs.record.config import Settings
from jobs.record.reproduction_marker import MARKER, is_running

PROVENANCE = "provenance.json"
TABLE = "table.json"
JOB_PREFIX = "job-"


@dataclass
class ReproductionFolder:
    """One stored reproduction: its folder and its own files."""

    folder: Path
    files: list[Path]
    job_id: int | None              # the service's job that wrote it; None: the CLI
    finished: datetime | None       # None: it never finished (or is running)
    newest_mtime: float             # of its files
    running: bool                   # a live process holds its marker

    @property
    def bytes(self) -> int:
        return sum(_size(path) for path in self.files)


def reproduction_folders(settings: Settings) -> list[ReproductionFolder]:
    """Every stored reproduction with at least one file, the CLI's of a figure before
    its jobs'."""
    root = settings.reproductions_dir
    if not root.is_dir():
        return []
    found = []
    for figure in sorted(root.iterdir()):
        if not figure.is_dir() or figure.is_symlink():
            continue
        found.append(_found(figure, [path for path in figure.iterdir() if _own(path)], None))
        for job in sorted(figure.glob(f"{JOB_PREFIX}*")):
            number = job.name.removeprefix(JOB_PREFIX)
            if job.is_dir() and not job.is_symlink() and number.isdigit():
                found.append(_found(job, list(_files(job)), int(number)))
    return [folder for folder in found if folder.files]


def reproduction_bytes(settings: Settings, job_ids: Collection[int] | None = None) -> int:
    """Bytes the stored reproductions take: all of them, or those of the jobs ``job_ids``
    (the CLI's count in no key's)."""
    return sum(found.bytes for found in reproduction_folders(settings)
               if job_ids is None or found.job_id in job_ids)


def _found(folder: Path, files: list[Path], job_id: int | None) -> ReproductionFolder:
    mtimes = [_mtime(path) for path in files]
    marked = folder / MARKER in files
    return ReproductionFolder(folder, files, job_id, None if marked else _finished(folder),
                              max(mtimes, default=0.0), marked and is_running(folder))


def _finished(folder: Path) -> datetime | None:
    """When the reproduction in ``folder`` finished: its provenance's ``finished_at``,
    else its table's time; None without a table."""
    try:
        finished = datetime.fromisoformat(
            json.loads((folder / PROVENANCE).read_text())["finished_at"])
        return finished if finished.tzinfo else finished.replace(tzinfo=UTC)
    except (OSError, ValueError, KeyError, TypeError):
        pass                # none, or unreadable: dated by its table
    table = folder / TABLE
    if not _own(table):
        return None
    return datetime.fromtimestamp(table.lstat().st_mtime, UTC)


def _own(path: Path) -> bool:
    """A file of a reproduction's (a link counts as one: removing it removes the link)."""
    return path.is_symlink() or path.is_file()


def _files(folder: Path) -> Iterator[Path]:
    yield from (path for path in folder.rglob("*") if _own(path))


def _size(path: Path) -> int:
    try:
        return path.lstat().st_size
    except OSError:
        return 0


def _mtime(path: Path) -> float:
    try:
        return path.lstat().st_mtime
    except OSError:
        return 0.0          # gone since the folder was listed (a run's draft marker)
