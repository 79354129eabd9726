"""What one API key holds on disk, for its storage quota (``Settings.key_quota_bytes``).

A key holds:

* the artifacts of the runs and sweeps its jobs stored (a job's ``run_id`` and
  ``sweep_id``; each file once): one query on the store;
* the images it uploaded for comparison (``uploaded_images/<key id>/``, at most a
  handful of files: a walk of that folder alone);
* the scenes it uploaded: each upload leaves an owner mark
  ``scenes/.owners/<key id>/<digest>`` holding the scene's bytes, counted while the
  scene is stored (gc removes the marks with their scene);
* the reproductions its reproduce jobs stored (``reproduce/<paper>-<figure>/job-<id>/``,
  jobs/record/reproduction_folders.py), running or done.

References and cache snapshots are shared: any key's later job reuses them, so they
count in the data folder's size (``max_data_bytes``) and in no key's quota; so do
the reproductions of the command line (``nirc-bench reproduce`` without a service) and
the runs a sweep's stages store (their keys are content keys, shared by every
sweep that needs them). The estimated files of a key's unfinished jobs are added by
the service, which knows how to estimate a job (service/api/quota.py).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from sqlalchemy import func, or_, select

from jobs.record.artifacts import PRIVATE_FILE_MODE, make_private_dir
from jobs.record.config import Settings
from jobs.record.models import Artifact, Job, JobStatus
from jobs.record.reproduction_folders import reproduction_bytes
from jobs.record.store import Store

#: The folder of the scenes' owner marks, inside the scenes folder (gc and the scene
#: loader skip names that start with a dot).
SCENE_OWNERS = ".owners"


def scene_owners_dir(settings: Settings) -> Path:
    return settings.scenes_dir / SCENE_OWNERS


def mark_scene_owner(settings: Settings, key_id: int, digest: str, scene_bytes: int) -> None:
    """Record that key ``key_id`` uploaded the stored scene ``digest`` of
    ``scene_bytes`` bytes (the same scene uploaded by two keys counts for both)."""
    folder = make_private_dir(scene_owners_dir(settings) / str(key_id))
    mark = folder / digest
    mark.write_text(str(scene_bytes))
    os.chmod(mark, PRIVATE_FILE_MODE)


def forget_scene(settings: Settings, digest: str) -> None:
    """Remove every key's owner mark of scene ``digest`` (the scene is gone)."""
    folder = scene_owners_dir(settings)
    if folder.is_dir():
        for mark in folder.glob(f"*/{digest}"):
            mark.unlink(missing_ok=True)


def _scene_bytes(settings: Settings, key_id: int) -> int:
    folder = scene_owners_dir(settings) / str(key_id)
    if not folder.is_dir():
        return 0
    total = 0
    for mark in folder.iterdir():
        if (settings.scenes_dir / mark.name).is_dir():
            try:
                total += int(mark.read_text() or 0)
            except (OSError, ValueError):
                continue        # a mark being written or removed: counted next time
    return total


def distinct_file_bytes(paths: Iterable[Path]) -> int:
    """Bytes the files ``paths`` take, each file once: hard links to one file (an image a
    key uploaded for several runs, service/api/routes/images.py) count once."""
    seen: dict[tuple[int, int], int] = {}
    for path in paths:
        if path.is_file():
            info = path.stat()
            seen[(info.st_dev, info.st_ino)] = info.st_size
    return sum(seen.values())


def _image_bytes(settings: Settings, key_id: int) -> int:
    folder = settings.uploaded_images_dir / str(key_id)
    if not folder.is_dir():
        return 0
    return distinct_file_bytes(folder.rglob("*.exr"))


def stored_bytes(store: Store, settings: Settings, key_id: int) -> int:
    """Bytes key ``key_id`` holds on disk: its jobs' runs' and sweeps' artifacts (each
    file once), its uploaded images and scenes, and its jobs' reproductions."""
    owned = Job.owner_key_id == key_id
    with store.session() as session:
        reproduce_jobs = set(session.scalars(select(Job.id).where(
            owned, Job.kind == "reproduce")))
        files = select(Artifact.path, func.max(Artifact.bytes).label("bytes")).where(or_(
            Artifact.run_id.in_(select(Job.run_id).where(owned, Job.run_id.is_not(None))),
            Artifact.sweep_id.in_(select(Job.sweep_id).where(owned, Job.sweep_id.is_not(None)))
        )).group_by(Artifact.path).subquery()
        artifacts = int(session.scalar(select(func.coalesce(func.sum(files.c.bytes), 0))) or 0)
    return (artifacts + _image_bytes(settings, key_id) + _scene_bytes(settings, key_id)
            + (reproduction_bytes(settings, reproduce_jobs) if reproduce_jobs else 0))


def unfinished_spec_keys(store: Store, key_id: int) -> list[str]:
    """The spec keys of the queued and running jobs (renders and sweeps; a sweep's
    stages go with it) of key ``key_id``: one narrow query, no spec read."""
    with store.session() as session:
        return list(session.scalars(select(Job.spec_key).where(
            Job.owner_key_id == key_id, Job.parent_id.is_(None),
            Job.status.in_([JobStatus.QUEUED.value, JobStatus.RUNNING.value]))))


def jobs_with_spec_keys(store: Store, spec_keys: Iterable[str]) -> list[Job]:
    """One job row per spec key of ``spec_keys`` (the rows of equal keys hold equal
    specs)."""
    keys = list(spec_keys)
    if not keys:
        return []
    with store.session() as session:
        rows = session.scalars(select(Job).where(Job.spec_key.in_(keys)))
        return list({row.spec_key: row for row in rows}.values())
