"""Response bodies of the REST API (request bodies are the job specs themselves)."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path
from typing import Any

from pydantic import BaseModel, Field

from jobs.ci.history import History
from jobs.protocol.results import RunResult, RunResultDetail
from jobs.protocol.versions import is_current
from jobs.record.models import JobStatus
from jobs.views.comparison import RunComparison
from service.api.data_paths import served

#: The status served for a running job whose cancel was requested: its runner stops it,
#: then it is 'canceled' (a served status, not stored: the row stays 'running' with
#: ``cancel_requested`` until the runner has stopped it).
CANCELING = "canceling"
STATUS_DESCRIPTION = ("queued, running, canceling (a cancel was requested: its runner "
                      "stops it, then it is canceled), succeeded, failed or canceled")


def served_status(job: Any) -> str:
    """``job``'s status as served: :data:`CANCELING` for a running job asked to stop."""
    if job.status == JobStatus.RUNNING.value and job.cancel_requested:
        return CANCELING
    return str(job.status)


class StageOut(BaseModel):
    """One stage of a sweep's task graph (jobs/execution/graph.py), itself a job."""

    id: int
    name: str
    status: str = Field(description=STATUS_DESCRIPTION)
    progress: dict[str, Any]
    attempts: int
    error: str | None
    work: dict[str, int] | None = Field(
        None, description="what the stage rendered and what it found stored (once succeeded)")


class JobOut(BaseModel):
    id: int
    kind: str
    status: str = Field(description=STATUS_DESCRIPTION)
    progress: dict[str, Any]
    attempts: int
    max_attempts: int
    worker: str | None
    error: str | None
    device_class: str
    run_id: int | None
    sweep_id: int | None
    parent_id: int | None
    work: dict[str, int] | None = Field(
        None, description="a stage job's work: what it rendered and what it found stored; "
                          "a render job's: reference_rendered and run_reused (0 or 1)")
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    spec: dict[str, Any]
    stages: list[StageOut] | None = None
    stalled: str | None = Field(
        None, description="why a running job whose lease expired does not run: "
                          "'storage: <cause>' while the service cannot write its database")

    @classmethod
    def of(cls, job: Any, stages: list[Any] | None = None,
           stalled: str | None = None, *, data_dir: Path) -> JobOut:
        """``job`` as served; a sweep with its ``stages``; ``stalled``: why it does not run.
        Its texts name files of the data folder ``data_dir`` relative to it
        (service/api/data_paths.py)."""
        out = cls.model_validate(job, from_attributes=True)
        out.status = served_status(job)
        out.error, out.stalled = served(job.error, data_dir), served(stalled, data_dir)
        if stages:
            out.stages = [StageOut(id=stage.id, name=stage.spec.get("name", ""),
                                   status=served_status(stage), progress=stage.progress,
                                   attempts=stage.attempts, error=served(stage.error, data_dir),
                                   work=stage.work)
                          for stage in stages]
        return out


class ArtifactOut(BaseModel):
    id: int
    kind: str
    seed: int | None = Field(None, description="the seed whose file it is (an image, preview "
                                               "or error map of one seed); null: the run's")
    media_type: str
    sha256: str
    bytes: int
    url: str

    @classmethod
    def of(cls, artifact: Any, seed_of: dict[int, int] | None = None) -> ArtifactOut:
        """``seed_of``: the seed of each of the run's seed results, by id."""
        return cls(id=artifact.id, kind=artifact.kind, media_type=artifact.media_type,
                   seed=(seed_of or {}).get(artifact.seed_result_id),
                   sha256=artifact.sha256, bytes=artifact.bytes,
                   url=f"/api/v1/artifacts/{artifact.id}")


#: A result row (jobs.protocol.results: the one public model of a run).
RunOut = RunResult
#: Runs side by side (jobs.views.comparison).
Comparison = RunComparison
#: A metric over commits with its step changes (jobs.ci.history).
HistoryOut = History


class RunDetail(RunResultDetail):
    """A run's every metric, timings, provenance (jobs.protocol.results) and its artifacts."""

    artifacts: list[ArtifactOut]

    @classmethod
    def of(cls, run: Any, **extra: Any) -> RunDetail:
        seed_of = {result.id: result.seed for result in run.seed_results}
        return super().of(run, artifacts=[ArtifactOut.of(a, seed_of) for a in run.artifacts],
                          **extra)


class SweepOut(BaseModel):
    id: int
    kind: str
    scene: str
    status: str
    spec: dict[str, Any]
    result: dict[str, Any]
    device_key: str
    estimator_versions: dict[str, int] | None = Field(
        description="method -> estimator version (null: stored before versions)")
    metric_version: int
    current: bool = Field(description="computed by today's estimator and metric versions")
    created_at: datetime
    finished_at: datetime | None
    artifacts: list[ArtifactOut]

    @classmethod
    def of(cls, sweep: Any, *, data_dir: Path) -> SweepOut:
        """``sweep`` as served, its result's texts naming files of the data folder
        ``data_dir`` relative to it (service/api/data_paths.py)."""
        versions = sweep.estimator_versions
        current = bool(versions) and all(is_current(method, version, sweep.metric_version)
                                         for method, version in versions.items())
        return cls(id=sweep.id, kind=sweep.kind, scene=sweep.scene_name, status=sweep.status,
                   spec=sweep.spec, result=served(sweep.result, data_dir),
                   device_key=sweep.device_key,
                   estimator_versions=versions, metric_version=sweep.metric_version,
                   current=current, created_at=sweep.created_at, finished_at=sweep.finished_at,
                   artifacts=[ArtifactOut.of(a) for a in sweep.artifacts])


class MethodOut(BaseModel):
    """A registered render method (renderers/methods)."""

    name: str
    label: str
    description: str
    version: int = Field(description="its estimator version, stored with its results")
    knob: str | None = Field(description="what equal-time calibration varies (null: none)")
    sweep: str | None = Field(description="its series label in sweeps (null: not swept)")
    source: str = Field(description="'built-in', or the entry point and package it came from")


class MethodsOut(BaseModel):
    methods: list[MethodOut]
    skipped_plugins: dict[str, str] = Field(
        description="entry points of nirc_bench.methods left out ('name = value' -> why)")


class SceneOut(BaseModel):
    name: str
    description: str


class SceneUploadOut(BaseModel):
    """A stored uploaded scene: use ``id`` as the ``scene`` of a job or sweep."""

    id: str = Field(description="upload:<digest>, the digest of the vetted XML and files")
    files: int = Field(description="files stored with the scene XML")
    bytes: int = Field(description="bytes stored in all")
