"""Retention (`nirc-bench gc`): unused references and unnamed files go, results stay;
a dry run only lists; young files are kept (a job in flight writes them first)."""

from __future__ import annotations

import os
import time
from datetime import UTC, datetime, timedelta

from typer.testing import CliRunner

from jobs.record import gc
from jobs.record.artifacts import ArtifactStore
from jobs.record.config import Settings
from jobs.record.db import open_store
from tests.jobs.factories import artifact_fields, reference_fields, run_fields

OLD = datetime.now(UTC) - timedelta(days=90)


def _age(path, days: float = 90) -> None:
    past = time.time() - days * 86400
    os.utime(path, (past, past))


def _data(store, settings: Settings) -> dict:
    """An unused old reference, a used one, an unnamed old and young artifact file,
    a named one, a stray reference file and an old scratch file."""
    refs = settings.references_dir
    refs.mkdir(parents=True)
    files = {}
    for name in ("unused.exr", "unused.variance.exr", "used.exr", "used.variance.exr",
                 "stray.exr"):
        (refs / name).write_bytes(b"x" * 100)
        _age(refs / name)
        files[name] = refs / name
    unused = store.add_reference(**reference_fields(
        "unused", image_path="unused.exr", variance_path="unused.variance.exr", created_at=OLD))
    used = store.add_reference(**reference_fields(
        "used", image_path="used.exr", variance_path="used.variance.exr", created_at=OLD))
    artifacts = ArtifactStore(settings.artifacts_dir)
    named = artifacts.put_bytes(b"named" * 10, ".exr")
    orphan = artifacts.put_bytes(b"orphan" * 10, ".exr")
    young = artifacts.put_bytes(b"young" * 10, ".exr")
    for blob in (named, orphan):
        _age(artifacts.path_of(blob.relpath))
    fields = artifact_fields("image", named.sha256)
    run = store.add_run(run_fields(reference_id=used.id), [], [{**fields, "path": named.relpath}])
    scratch = settings.data_dir / "tmp" / ".tmp-abc.exr"
    scratch.parent.mkdir(parents=True)
    scratch.write_bytes(b"s" * 7)
    _age(scratch)
    return {"unused": unused, "used": used, "run": run, "files": files, "scratch": scratch,
            "named": artifacts.path_of(named.relpath), "young": artifacts.path_of(young.relpath),
            "orphan": artifacts.path_of(orphan.relpath)}


def test_gc_lists_then_removes_what_no_result_needs(store, settings):
    data = _data(store, settings)
    plan = gc.plan(store, settings)
    listed = {(r.what, r.reference_id or str(r.path)) for r in plan.removals}
    assert listed == {("reference", data["unused"].id),
                      ("reference file", str(data["files"]["stray.exr"])),
                      ("artifact file", str(data["orphan"])),
                      ("scratch file", str(data["scratch"]))}
    assert plan.bytes == 200 + 100 + 60 + 7
    assert data["orphan"].exists() and store.get_reference(data["unused"].id)  # a plan only
    assert gc.apply(store, settings, plan) == plan.bytes
    assert store.get_reference(data["unused"].id) is None
    assert store.get_reference(data["used"].id) is not None
    assert store.get_run(data["run"].id).artifacts[0].path
    for kept in (data["named"], data["young"], data["files"]["used.exr"]):
        assert kept.exists()
    for gone in (data["orphan"], data["scratch"], data["files"]["unused.exr"],
                 data["files"]["stray.exr"]):
        assert not gone.exists()
    assert gc.plan(store, settings).removals == []
    # With no age limit, the young unnamed file goes too.
    assert [r.path for r in gc.plan(store, settings, keep_days=0).removals] == [data["young"]]


def test_gc_command_is_a_dry_run_unless_applied(tmp_path, monkeypatch):
    from service.cli import app

    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    settings = Settings(data_dir=tmp_path / "data")
    store = open_store(settings)
    data = _data(store, settings)
    store.close()
    runner = CliRunner()
    dry = runner.invoke(app, ["gc", "--data-dir", str(settings.data_dir)])
    assert dry.exit_code == 0, dry.output
    assert "would remove 4 items, 367 bytes" in dry.output and "--apply" in dry.output
    assert data["orphan"].exists()
    applied = runner.invoke(app, ["gc", "--apply", "--data-dir", str(settings.data_dir)])
    assert applied.exit_code == 0 and "removed 4 items, 367 bytes" in applied.output
    assert not data["orphan"].exists() and data["named"].exists()


def test_gc_applies_the_retention_policy_to_results_artifacts(store, settings):
    """Before: nothing ever removed a result's images. After: gc removes the artifacts
    (rows and files) of runs older than artifact_keep_days, then the oldest first while
    the store is over artifact_max_bytes; the runs themselves (their metrics) stay, and
    a file another row still names stays."""
    artifacts = ArtifactStore(settings.artifacts_dir)
    blobs = {name: artifacts.put_bytes(name.encode() * 100, ".exr")
             for name in ("ancient", "old", "new")}
    shared = artifacts.put_bytes(b"shared" * 100, ".png")
    runs = {}
    for name, days in (("ancient", 400), ("old", 20), ("new", 1)):
        rows = [{**artifact_fields("image", blobs[name].sha256), "path": blobs[name].relpath,
                 "bytes": 100 * len(name)},
                {**artifact_fields("preview", shared.sha256), "path": shared.relpath,
                 "bytes": 600}]
        runs[name] = store.add_run(run_fields(
            created_at=datetime.now(UTC) - timedelta(days=days)), [], rows)
    by_age = settings.model_copy(update={"artifact_keep_days": 365.0})
    plan = gc.plan(store, by_age)
    assert [(r.what, r.owner_id) for r in plan.removals] == [
        ("run artifacts", runs["ancient"].id)]
    gc.apply(store, by_age, plan)
    assert store.get_run(runs["ancient"].id).artifacts == []        # the result stays
    assert not artifacts.path_of(blobs["ancient"].relpath).exists()
    assert artifacts.path_of(shared.relpath).exists()               # others name it
    by_size = settings.model_copy(update={"artifact_keep_days": None,
                                          "artifact_max_bytes": 600 + 300 + 100})
    plan = gc.plan(store, by_size)
    assert [r.owner_id for r in plan.removals] == [runs["old"].id]
    gc.apply(store, by_size, plan)
    assert [a.kind for a in store.get_run(runs["new"].id).artifacts] == ["image", "preview"]
    assert gc.plan(store, by_size).removals == []


def test_gc_removes_uploaded_images_with_their_run_s_artifacts_or_past_their_lifetime(
        store, settings):
    """An image uploaded for a run (``<key>/<run>/<sha>.exr``) stays while its run has
    artifacts and it is younger than gc_keep_days; it goes once old, once its run's
    artifacts are gone, or with the artifacts this plan removes."""
    artifacts = ArtifactStore(settings.artifacts_dir)

    def run_with_image(days: float) -> int:
        blob = artifacts.put_bytes(f"image {days}".encode() * 10, ".exr")
        return store.add_run(run_fields(created_at=datetime.now(UTC) - timedelta(days=days)),
                             [], [{**artifact_fields("image", blob.sha256),
                                   "path": blob.relpath}]).id

    def uploaded(run_id: int, name: str, age_days: float = 0.0):
        path = settings.uploaded_images_dir / "1" / str(run_id) / f"{name}.exr"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"u" * 10)
        _age(path, age_days)
        return path

    kept_run, expiring_run = run_with_image(1), run_with_image(400)
    bare_run = store.add_run(run_fields(), [], []).id                 # no artifacts
    kept = uploaded(kept_run, "kept")
    old = uploaded(kept_run, "old", age_days=60)
    with_expiring = uploaded(expiring_run, "expiring")
    with_bare = uploaded(bare_run, "bare")
    unkeyed = uploaded(999_999, "no-run")                             # no such run
    policy = settings.model_copy(update={"artifact_keep_days": 365.0})
    plan = gc.plan(store, policy)
    images = {r.path for r in plan.removals if r.what == "uploaded image"}
    assert images == {old, with_expiring, with_bare, unkeyed}
    gc.apply(store, policy, plan)
    assert kept.exists() and not any(path.exists() for path in images)
