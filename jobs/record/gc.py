"""Retention of the data folder: what `nirc-bench gc` removes.

Run and sweep rows (the results: metrics, timings, provenance) are never removed.
What can go:

* references that no run and no cache snapshot uses (their row, their artifact
  rows, their image and variance files): a later job renders them again;
* stored scenes (uploads and scene-root copies, ``data/scenes/<digest>``) that no
  job, run, sweep, reference or cache snapshot names;
* files in the artifact store that no artifact row names (left by a job that
  died before storing its run, or by rows removed since);
* files in the references folder that no reference row names;
* scratch files (``data/tmp``) and interrupted writes (``.tmp-*``);
* images uploaded for comparison (``data/uploaded_images``) since their last upload;

all of these once older than ``Settings.gc_keep_days`` (the age limit protects a job
in flight: it writes its files before the rows that name them). And, by the
retention policy, the **artifacts of runs and sweeps** (images, error maps,
previews, plots: their rows and files; the results stay): those of runs and sweeps
created more than ``artifact_keep_days`` ago, and, while the artifact store holds
more than ``artifact_max_bytes``, those of the oldest runs and sweeps first; a run the
user named or tagged (``nirc-bench runs tag``) keeps its artifacts. The **reproduced
figures** (``data/reproduce``: tables, PNGs, provenance; jobs/record/reproduction_folders.py)
go by the same policy, each dated by when it finished and counted in the same size
beside the artifact store; one that never finished goes once its files are older than
``gc_keep_days``; the folder of a reproduce job queued or running is never removed, nor
one whose run (a job's, or the command line's ``nirc-bench reproduce``) holds its marker
while its process lives (jobs/record/reproduction_marker.py; a marker left by a process
that is gone makes its folder an unfinished reproduction).
Artifacts of references and cache snapshots are kept: later jobs reuse them. An
uploaded image goes with its run's artifacts (those this plan removes, or none left)
whatever its age: nothing is left to compare it with; the run's and key's folders go
once empty. A removed scene takes its owners' marks (jobs/record/usage.py) with it.
The service runs the same plan on its own every ``retention_interval_h`` hours
(service/retention.py).

:func:`plan` only looks; :func:`apply` removes what a plan lists.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path

from sqlalchemy import delete, func, select

from jobs.record.config import Settings
from jobs.record.models import Artifact, CacheSnapshot, Job, JobStatus, Reference, Run, Sweep
from jobs.record.reproduction_folders import JOB_PREFIX, PROVENANCE, reproduction_folders
from jobs.record.reproduction_marker import is_running
from jobs.record.store import Store
from jobs.record.usage import forget_scene


@dataclass
class Removal:
    """One thing gc removes: a file or folder (``path``), a reference row with its
    files, or the artifacts (rows and unshared files) of one run or sweep."""

    what: str       # 'reference', 'scene', 'run artifacts', 'sweep artifacts', '... file'
    path: Path | None
    bytes: int
    reference_id: int | None = None
    files: list[Path] = field(default_factory=list)   # a reference's own files
    artifact_ids: list[int] = field(default_factory=list)
    owner_id: int | None = None                       # the run or sweep of artifacts

    @property
    def name(self) -> str:
        if self.reference_id is not None:
            return f"reference {self.reference_id}"
        if self.owner_id is not None:
            return f"{self.what.split()[0]} {self.owner_id}"
        return str(self.path)


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


def named_scenes(store: Store) -> set[str]:
    """The stored scene ids (``upload:<d>``, ``staged:<d>``) that a row names: a job's
    spec (a sweep's stages name its scene too), a run, sweep, reference or snapshot."""
    with store.session() as session:
        names = set(session.scalars(select(Job.spec["scene"].as_string())
                                    .where(Job.parent_id.is_(None))))
        for column in (Run.scene_name, Sweep.scene_name, Reference.scene_name,
                       CacheSnapshot.scene_name):
            names |= set(session.scalars(select(column).distinct()))
    return {name for name in names if isinstance(name, str) and ":" in name}


def _scenes(store: Store, settings: Settings, old_mtime: float) -> list[Removal]:
    folder = settings.scenes_dir
    if not folder.is_dir():
        return []
    named = {name.split(":", 1)[1] for name in named_scenes(store)}
    return [Removal("scene", scene, sum(map(_size, _files(scene))))
            for scene in sorted(folder.iterdir())
            if scene.is_dir() and not scene.name.startswith(".")
            and scene.name not in named and scene.stat().st_mtime < old_mtime]


def _uploaded_images(store: Store, settings: Settings, old_mtime: float,
                     expiring_runs: set[int]) -> list[Removal]:
    """Uploaded images (``<key>/<run>/<sha256>.exr``) past their lifetime, and those of
    runs whose artifacts are gone or go in this plan (``expiring_runs``)."""
    images = list(_files(settings.uploaded_images_dir))
    runs = {int(path.parent.name) for path in images if path.parent.name.isdigit()}
    with store.session() as session:
        with_artifacts = set(session.scalars(select(Artifact.run_id).distinct().where(
            Artifact.run_id.in_(runs)))) if runs else set()
    gone = (runs - with_artifacts) | expiring_runs
    return [Removal("uploaded image", path, _size(path)) for path in images
            if path.stat().st_mtime < old_mtime
            or path.parent.name.isdigit() and int(path.parent.name) in gone]


def active_reproductions(store: Store) -> set[int]:
    """The ids of the reproduce jobs queued or running: their folders are never removed."""
    with store.session() as session:
        return set(session.scalars(select(Job.id).where(
            Job.kind == "reproduce",
            Job.status.in_((JobStatus.QUEUED.value, JobStatus.RUNNING.value)))))


def _reproductions(store: Store, settings: Settings, old_mtime: float
                   ) -> tuple[list[Removal], list[tuple[datetime, Removal]]]:
    """The stored reproductions but those of queued or running jobs and those a live run
    holds: the unfinished ones whose files are all older than ``old_mtime`` (to remove),
    and the finished ones with when they finished (for the retention policy)."""
    active = active_reproductions(store)
    unfinished: list[Removal] = []
    finished: list[tuple[datetime, Removal]] = []
    for found in reproduction_folders(settings):
        if found.job_id in active or found.running:
            continue
        if found.finished is not None:
            finished.append((found.finished, Removal(
                "reproduction", found.folder, found.bytes, files=found.files)))
        elif found.newest_mtime < old_mtime:
            unfinished.append(Removal("unfinished reproduction", found.folder, found.bytes,
                                      files=found.files))
    return unfinished, finished


def _expired_artifacts(store: Store, settings: Settings,
                       reproductions: list[tuple[datetime, Removal]]) -> list[Removal]:
    """The artifacts of runs and sweeps, and the stored reproductions (``reproductions``:
    when each finished), past the retention policy: by age, then, oldest first, while
    the artifact store and the reproductions together are over its size."""
    keep_days, max_bytes = settings.artifact_keep_days, settings.artifact_max_bytes
    if keep_days is None and max_bytes is None:
        return []
    with store.session() as session:
        rows = session.execute(
            select(Artifact.id, Artifact.bytes, Artifact.run_id, Artifact.sweep_id,
                   func.coalesce(Run.created_at, Sweep.created_at), Run.name, Run.tags)
            .outerjoin(Run, Artifact.run_id == Run.id)
            .outerjoin(Sweep, Artifact.sweep_id == Sweep.id)
            .where(Artifact.reference_id.is_(None), Artifact.snapshot_id.is_(None),
                   (Artifact.run_id.is_not(None)) | (Artifact.sweep_id.is_not(None)))).all()
        total = int(session.scalar(select(func.coalesce(func.sum(Artifact.bytes), 0))) or 0)
    owners: dict[tuple[str, int], Removal] = {}
    ages: dict[tuple[str, int], datetime] = {}
    for artifact_id, size, run_id, sweep_id, created, name, tags in rows:
        if name is not None or tags:
            continue            # a run the user named or tagged is kept
        owner = ("run", run_id) if run_id is not None else ("sweep", sweep_id)
        removal = owners.setdefault(owner, Removal(f"{owner[0]} artifacts", None, 0,
                                                   owner_id=owner[1]))
        removal.artifact_ids.append(artifact_id)
        removal.bytes += size
        ages[owner] = created
    candidates = [(ages[owner], f"{owner[0]} {owner[1]:012d}", owners[owner])
                  for owner in owners]
    candidates += [(finished, str(removal.path), removal)
                   for finished, removal in reproductions]
    total += sum(removal.bytes for _, removal in reproductions)
    cutoff = datetime.now(UTC) - timedelta(days=keep_days) if keep_days is not None else None
    chosen: list[Removal] = []
    for created, _order, removal in sorted(candidates, key=lambda c: c[:2]):
        expired = cutoff is not None and created < cutoff
        over = max_bytes is not None and total > max_bytes
        if expired or over:
            chosen.append(removal)
            total -= removal.bytes
    return chosen


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
    removals += _scenes(store, settings, old_mtime)
    unfinished, reproductions = _reproductions(store, settings, old_mtime)
    removals += unfinished
    expired = _expired_artifacts(store, settings, reproductions)
    removals += expired
    removals += _uploaded_images(store, settings, old_mtime, {
        removal.owner_id for removal in expired
        if removal.what == "run artifacts" and removal.owner_id is not None})
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
    freed += _remove_artifact_rows(store, settings, [
        artifact_id for removal in gc_plan.removals for artifact_id in removal.artifact_ids])
    # A scene named since the plan (a job submitted meanwhile) stays, and so does the
    # folder of a reproduce job queued again, or of a reproduction started, meanwhile.
    named = {name.split(":", 1)[1] for name in named_scenes(store)}
    active = active_reproductions(store)
    for removal in gc_plan.removals:
        if removal.reference_id in kept:
            continue
        if removal.what.endswith("reproduction"):
            freed += _remove_reproduction(removal, settings, active)
            continue
        if removal.what == "scene":
            if removal.path.name not in named:
                freed += sum(map(_size, _files(removal.path)))
                shutil.rmtree(removal.path, ignore_errors=True)
                forget_scene(settings, removal.path.name)
            continue
        for path in [*removal.files, *([removal.path] if removal.path else [])]:
            freed += _size(path)
            path.unlink(missing_ok=True)
        if removal.what == "uploaded image" and removal.path is not None:
            _remove_empty(removal.path.parent, settings.uploaded_images_dir)
    return freed


def _remove_reproduction(removal: Removal, settings: Settings, active: set[int]) -> int:
    """Remove a reproduction's files (its provenance first: readers pass over it from
    then on) and the folders left empty, unless its job (``removal.path`` is its
    folder) is queued or running or a live run holds its marker; bytes freed."""
    if removal.path.name.startswith(JOB_PREFIX) and \
            int(removal.path.name.removeprefix(JOB_PREFIX)) in active:
        return 0
    if is_running(removal.path):
        return 0
    freed = 0
    for path in sorted(removal.files, key=lambda path: path.name != PROVENANCE):
        freed += _size(path)
        path.unlink(missing_ok=True)
    for folder in sorted({path.parent for path in removal.files}, key=lambda f: -len(f.parts)):
        _remove_empty(folder, settings.reproductions_dir)
    return freed


def _remove_empty(folder: Path, root: Path) -> None:
    """Remove ``folder`` and its parents up to ``root`` (kept) while they are empty: the
    run and key folders of uploaded images that are gone, a reproduction's folders."""
    while folder != root and root in folder.parents:
        try:
            folder.rmdir()
        except OSError:         # not empty (or gone): an upload still lives there
            return
        folder = folder.parent


def _remove_artifact_rows(store: Store, settings: Settings, artifact_ids: list[int]) -> int:
    """Delete these artifact rows, then the files no remaining row names; bytes freed."""
    if not artifact_ids:
        return 0
    with store.session(write=True) as session:
        paths = set(session.scalars(select(Artifact.path).where(Artifact.id.in_(artifact_ids))))
        session.execute(delete(Artifact).where(Artifact.id.in_(artifact_ids)))
        still_named = set(session.scalars(select(Artifact.path).where(Artifact.path.in_(paths))))
    freed = 0
    for relative in paths - still_named:
        path = settings.artifacts_dir / relative
        freed += _size(path)
        path.unlink(missing_ok=True)
    return freed
