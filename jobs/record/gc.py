"""Retention of the data folder: what `nirc-bench gc` removes.

Runs and sweeps are results and are never removed. What can go is what no
stored result needs, once it is older than ``Settings.gc_keep_days``:

* references that no run and no cache snapshot uses (their row, their artifact
  rows, their image and variance files): a later job renders them again;
* files in the artifact store that no artifact row names (left by a job that
  died before storing its run, or by rows removed since);
* files in the references folder that no reference row names;
* scratch files (``data/tmp``) and interrupted writes (``.tmp-*``).

The age limit protects a job in flight: it writes its files before the rows
that name them. :func:`plan` only looks; :func:`apply` removes what a plan lists.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path

from sqlalchemy import delete, select

from jobs.record.config import Settings
from jobs.record.models import Artifact, CacheSnapshot, Reference, Run
from jobs.record.store import Store


@dataclass
class Removal:
    """One thing gc removes: a file (``path``), or a reference row with its files."""

    what: str                  # 'reference', 'artifact file', 'reference file', 'scratch file'
    path: Path | None
    bytes: int
    reference_id: int | None = None
    files: list[Path] = field(default_factory=list)   # a reference's own files


@dataclass
class Plan:
    removals: list[Removal]

    @property
    def bytes(self) -> int:
        return sum(removal.bytes for removal in self.removals)


def _files(folder: Path) -> Iterator[Path]:
    if folder.is_dir():
        yield from (path for path in folder.rglob("*") if path.is_file())


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def plan(store: Store, settings: Settings, keep_days: float | None = None) -> Plan:
    """What gc would remove now (nothing is touched)."""
    keep_days = settings.gc_keep_days if keep_days is None else keep_days
    cutoff = datetime.now(UTC) - timedelta(days=keep_days)
    old_mtime = time.time() - keep_days * 86400.0
    removals: list[Removal] = []
    with store.session() as session:
        used = select(Run.reference_id).where(Run.reference_id.is_not(None)).union(
            select(CacheSnapshot.reference_id).where(CacheSnapshot.reference_id.is_not(None)))
        unused = session.scalars(select(Reference).where(
            Reference.id.not_in(used), Reference.created_at < cutoff)).all()
        reference_files = session.execute(
            select(Reference.image_path, Reference.variance_path)).all()
        artifact_paths = set(session.scalars(select(Artifact.path)))
        unused_artifacts = {row.path for row in session.scalars(
            select(Artifact).where(Artifact.reference_id.in_([r.id for r in unused])))}
    for row in unused:
        files = [settings.references_dir / row.image_path,
                 settings.references_dir / row.variance_path]
        removals.append(Removal("reference", None, sum(map(_size, files)), row.id, files))
    # Reference files named by a row that stays are kept; those of a removed row go with it.
    named = {settings.references_dir / name for names in reference_files for name in names}
    for path in _files(settings.references_dir):
        if path not in named and path.stat().st_mtime < old_mtime:
            removals.append(Removal("reference file", path, _size(path)))
    still_named = artifact_paths - unused_artifacts
    for path in _files(settings.artifacts_dir):
        relative = path.relative_to(settings.artifacts_dir).as_posix()
        if relative not in still_named and path.stat().st_mtime < old_mtime:
            # An artifact of a removed reference is removed now only if no other row
            # names the same content (content-addressed: one file, many rows).
            if relative in unused_artifacts:
                continue        # decided after the rows are gone (see apply)
            removals.append(Removal("artifact file", path, _size(path)))
    for path in _files(settings.data_dir / "tmp"):
        if path.stat().st_mtime < old_mtime:
            removals.append(Removal("scratch file", path, _size(path)))
    return Plan(removals)


def apply(store: Store, settings: Settings, gc_plan: Plan) -> int:
    """Remove what ``gc_plan`` lists; returns the bytes freed. Reference rows go first
    (their artifact rows with them), then every listed file."""
    freed = 0
    reference_ids = [r.reference_id for r in gc_plan.removals if r.reference_id is not None]
    if reference_ids:
        with store.session(write=True) as session:
            paths = set(session.scalars(select(Artifact.path).where(
                Artifact.reference_id.in_(reference_ids))))
            # Only references still unused now (a job may have used one since the plan).
            used = select(Run.reference_id).where(Run.reference_id.is_not(None)).union(
                select(CacheSnapshot.reference_id).where(
                    CacheSnapshot.reference_id.is_not(None)))
            session.execute(delete(Reference).where(Reference.id.in_(reference_ids),
                                                    Reference.id.not_in(used)))
            still_named = set(session.scalars(select(Artifact.path).where(
                Artifact.path.in_(paths)))) if paths else set()
            kept = set(session.scalars(select(Reference.id).where(
                Reference.id.in_(reference_ids))))
        for relative in paths - still_named:
            path = settings.artifacts_dir / relative
            freed += _size(path)
            path.unlink(missing_ok=True)
    else:
        kept = set()
    for removal in gc_plan.removals:
        if removal.reference_id in kept:
            continue
        for path in [*removal.files, *([removal.path] if removal.path else [])]:
            freed += _size(path)
            path.unlink(missing_ok=True)
    return freed
