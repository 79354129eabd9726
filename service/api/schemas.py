"""Response bodies of the REST API (request bodies are the job specs themselves)."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, Field, create_model

from jobs.protocol.versions import is_current
from metrics.registry import LISTED, Metric, row_values


class StageOut(BaseModel):
    """One stage of a sweep's task graph (jobs/execution/graph.py), itself a job."""

    id: int
    name: str
    status: str
    progress: dict[str, Any]
    attempts: int
    error: str | None
    work: dict[str, int] | None = Field(
        None, description="what the stage rendered and what it found stored (once succeeded)")


class JobOut(BaseModel):
    id: int
    kind: str
    status: str
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
        None, description="a stage job's work: what it rendered and what it found stored")
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    spec: dict[str, Any]
    stages: list[StageOut] | None = None

    @classmethod
    def of(cls, job: Any, stages: list[Any] | None = None) -> JobOut:
        """``job`` as served; a sweep with its ``stages``."""
        out = cls.model_validate(job, from_attributes=True)
        if stages:
            out.stages = [StageOut(id=stage.id, name=stage.spec.get("name", ""),
                                   status=stage.status, progress=stage.progress,
                                   attempts=stage.attempts, error=stage.error,
                                   work=stage.work)
                          for stage in stages]
        return out


class ArtifactOut(BaseModel):
    id: int
    kind: str
    media_type: str
    sha256: str
    bytes: int
    url: str

    @classmethod
    def of(cls, artifact: Any) -> ArtifactOut:
        return cls(id=artifact.id, kind=artifact.kind, media_type=artifact.media_type,
                   sha256=artifact.sha256, bytes=artifact.bytes,
                   url=f"/api/v1/artifacts/{artifact.id}")


def _metric_fields(metrics: tuple[Metric, ...]) -> dict[str, Any]:
    """RunOut's metric fields: ``<field>`` per listed metric (and ``<field>_ci95``)."""
    fields: dict[str, Any] = {}
    for m in metrics:
        unit = f" [{m.unit}]" if m.unit else ""
        fields[m.field] = (float | None, Field(
            description=f"{m.description}{unit}; {m.direction} is better (stored as "
                        f"metrics.{m.key}; null when withheld or not computed)"))
        if m.ci_key:
            fields[f"{m.field}_ci95"] = (list[float] | None, Field(
                description=f"Student-t 95 % interval of {m.label} over the seeds"))
    return fields


#: The metric columns of a result row, generated from metrics.registry.
_RunMetrics = create_model("_RunMetrics", **_metric_fields(LISTED))


class RunOut(_RunMetrics):
    """A result row: what a results list or a comparison shows of a run (the metric
    fields, e.g. mrse, mrse_ci95, rbias2, rvar, flip, psnr, come from metrics.registry)."""

    id: int
    created_at: datetime
    scene: str
    scene_fingerprint: str
    method: str
    params: dict[str, Any]
    resolution: list[int]
    spp: int
    frames: int
    seeds: int
    seconds_per_frame: float | None
    device_key: str
    quality: dict[str, Any]
    ref_floor_ratio_rbias2: float | None = Field(
        None, description="reference noise floor mean Var[R]/(R^2+eps) over |rBias^2|")
    ref_floor_ratio_mrse: float | None = Field(
        None, description="reference noise floor over |MRSE less the floor|")
    warnings: list[str] = Field(
        default_factory=list, description="e.g. the reference floor is above 10 % of a metric")
    verdict: str | None = Field(
        description="quality verdict (ok, untrained-cache, nonfinite, negative-radiance, "
                    "degenerate-reference, no-emitter); null for runs stored before verdicts")
    withheld: list[str] = Field(description="metrics the verdict makes meaningless (null above)")
    estimator_version: int
    metric_version: int
    current: bool = Field(description="computed by today's estimator and metric versions")

    @classmethod
    def of(cls, run: Any) -> RunOut:
        m, q = run.metrics, run.quality
        return cls(**row_values(m), id=run.id, created_at=run.created_at, scene=run.scene_name,
                   scene_fingerprint=run.scene_fingerprint, method=run.method,
                   params={k: v for k, v in run.params.items() if k != "spec"},
                   resolution=[run.width, run.height], spp=run.spp, frames=run.frames,
                   seeds=run.seeds, seconds_per_frame=run.timings.get("seconds_per_frame"),
                   device_key=run.device_key, quality=q, verdict=q.get("verdict"),
                   withheld=q.get("withheld", []), estimator_version=run.estimator_version,
                   metric_version=run.metric_version,
                   current=is_current(run.method, run.estimator_version, run.metric_version),
                   ref_floor_ratio_rbias2=m.get("ref_floor_ratio_rbias2"),
                   ref_floor_ratio_mrse=m.get("ref_floor_ratio_mrse"),
                   warnings=m.get("warnings") or [])


class SeedOut(BaseModel):
    seed: int
    metrics: dict[str, Any]
    timings: dict[str, Any]


class RunDetail(RunOut):
    metrics: dict[str, Any]
    timings: dict[str, Any]
    path_stats: dict[str, Any]
    device: dict[str, Any]
    versions: dict[str, Any]
    git_commit: str | None
    reference_id: int | None
    per_seed: list[SeedOut]
    artifacts: list[ArtifactOut]

    @classmethod
    def of(cls, run: Any) -> RunDetail:
        base = RunOut.of(run).model_dump()
        return cls(**base, metrics=run.metrics, timings=run.timings, path_stats=run.path_stats,
                   device=run.device, versions=run.versions, git_commit=run.git_commit,
                   reference_id=run.reference_id,
                   per_seed=[SeedOut(seed=s.seed, metrics=s.metrics, timings=s.timings)
                             for s in run.seed_results],
                   artifacts=[ArtifactOut.of(a) for a in run.artifacts])


class Comparison(BaseModel):
    runs: list[RunOut]
    same_device: bool
    same_reference_scene: bool
    metric_version: int = Field(description="every compared run was scored under it")
    estimator_versions: dict[str, list[int]] = Field(
        description="method -> the estimator versions among the runs; two versions of one "
                    "method are different estimators, not repeats")
    note: str


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
    def of(cls, sweep: Any) -> SweepOut:
        versions = sweep.estimator_versions
        current = bool(versions) and all(is_current(method, version, sweep.metric_version)
                                         for method, version in versions.items())
        return cls(id=sweep.id, kind=sweep.kind, scene=sweep.scene_name, status=sweep.status,
                   spec=sweep.spec, result=sweep.result, device_key=sweep.device_key,
                   estimator_versions=versions, metric_version=sweep.metric_version,
                   current=current, created_at=sweep.created_at, finished_at=sweep.finished_at,
                   artifacts=[ArtifactOut.of(a) for a in sweep.artifacts])


class SceneOut(BaseModel):
    name: str
    description: str


class SceneUploadOut(BaseModel):
    """A stored uploaded scene: use ``id`` as the ``scene`` of a job or sweep."""

    id: str = Field(description="upload:<digest>, the digest of the vetted XML and files")
    files: int = Field(description="files stored with the scene XML")
    bytes: int = Field(description="bytes stored in all")
