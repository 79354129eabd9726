"""Results: runs, comparisons, sweeps, artifacts, scenes, and the metric registry."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, Response, status
from fastapi.responses import FileResponse

from jobs.protocol.versions import current_estimator_versions
from jobs.record.artifacts import ArtifactStore
from jobs.record.models import Artifact
from jobs.views.comparison import ComparisonError, compare_runs
from metrics import METRIC_VERSION
from metrics.imageio import ImageReadError, png_bytes, read_exr
from metrics.preview import tonemap_preview
from metrics.registry import METRICS
from renderers.methods import METHOD_SOURCES, METHODS, SKIPPED_PLUGINS
from renderers.scenes import builtin_names, describe
from service.api.deps import RowId, SettingsDep, StoreDep
from service.api.schemas import (
    Comparison,
    MethodOut,
    MethodsOut,
    RunDetail,
    RunOut,
    SceneOut,
    SweepOut,
)
from service.api.unprocessable import unprocessable

router = APIRouter(prefix="/api/v1", tags=["results"])

#: A text filter; no NUL characters (PostgreSQL rejects them in strings).
Filter = Annotated[str | None, Query(max_length=500, pattern=r"^[^\x00]*$")]
IncludeOld = Annotated[bool, Query(description="also results of older estimator or metric "
                                               "versions (each says whether it is current)")]


def _not_found(what: str) -> HTTPException:
    return HTTPException(status.HTTP_404_NOT_FOUND, f"no {what}")


def _found(row: Any, what: str) -> Any:
    """``row``, or a 404 naming ``what`` when it is None."""
    if row is None:
        raise _not_found(what)
    return row


@router.get("/results", response_model=list[RunOut])
def list_results(store: StoreDep, scene: Filter = None, method: Filter = None,
                 device: Filter = None, include_old: IncludeOld = False,
                 limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> list[RunOut]:
    """Stored runs, newest first, filtered by scene name, method and device key; only
    runs of today's estimator and metric versions unless ``include_old``."""
    versions = {} if include_old else {"current": current_estimator_versions(),
                                       "metric_version": METRIC_VERSION}
    return [RunOut.of(run)
            for run in store.list_runs(scene, method, device, limit=limit, **versions)]


@router.get("/metrics")
def list_metrics() -> list[dict[str, Any]]:
    """The metric registry (metrics/registry.py), in display order: per metric its
    ``name``, ``label``, ``unit``, ``direction`` (lower or higher is better), ``aggregate``
    (how the seeds reduce), stored ``key`` / ``seed_key`` / ``ci_key``, result-row ``field``
    / ``ci_field`` (null: run details only), ``log_axis``, ``needs_k2``, ``sweep_plot`` and
    the ``verdict_name`` a quality verdict withholds it under."""
    return [m.to_json() for m in METRICS]


@router.get("/methods", response_model=MethodsOut)
def list_methods() -> MethodsOut:
    """The method registry (renderers/methods): the built-in methods, then those other
    packages register under the entry-point group ``nirc_bench.methods``, each with where
    it comes from; and the entry points that were left out, with why."""
    return MethodsOut(
        methods=[MethodOut(name=name, label=m.label or name, description=m.description,
                           version=m.version, knob=m.knob.name if m.knob else None,
                           sweep=m.sweep.label if m.sweep else None,
                           source=METHOD_SOURCES[name]) for name, m in METHODS.items()],
        skipped_plugins=SKIPPED_PLUGINS)


@router.get("/runs/{run_id}", response_model=RunDetail)
def get_run(run_id: RowId, store: StoreDep) -> RunDetail:
    """A run's metrics per seed and aggregated, timings, provenance and artifacts."""
    return RunDetail.of(_found(store.get_run(run_id), f"run {run_id}"))


@router.get("/compare", response_model=Comparison)
def compare(store: StoreDep,
            runs: Annotated[str, Query(pattern=r"^[1-9]\d{0,8}(,[1-9]\d{0,8}){1,19}$",
                                       description="2 to 20 run ids, e.g. 3,7")]) -> Comparison:
    """Runs side by side: the settings and parameters that differ, and each later run's
    metrics against the first's (with the Welch 95 % interval of the difference where
    both have 3 or more seeds); timings compare only when the device is the same. Runs
    scored under different metric versions are refused (422); two estimator versions of
    one method are flagged in the note."""
    found = [_found(store.get_run(run_id), f"run {run_id}")
             for run_id in dict.fromkeys(int(part) for part in runs.split(","))]
    try:
        return compare_runs(found)
    except ComparisonError as err:
        raise unprocessable(str(err), ("query", "runs")) from None


@router.get("/sweeps", response_model=list[SweepOut])
def list_sweeps(store: StoreDep, settings: SettingsDep, scene: Filter = None,
                include_old: IncludeOld = False,
                limit: Annotated[int, Query(ge=1, le=500)] = 50) -> list[SweepOut]:
    """Sweeps, newest first, optionally of one scene; only those scored under today's
    metric version unless ``include_old`` (``current`` also checks the estimators)."""
    return [SweepOut.of(sweep, data_dir=settings.data_dir) for sweep in store.list_sweeps(
        scene, limit=limit, metric_version=None if include_old else METRIC_VERSION)]


@router.get("/references/{reference_id}/preview.png", response_class=Response)
def reference_preview(reference_id: RowId, store: StoreDep, settings: SettingsDep) -> Response:
    """The tone-mapped preview of a converged reference (PNG, rendered on request)."""
    reference = _found(store.get_reference(reference_id), f"reference {reference_id}")
    try:
        image = read_exr(settings.references_dir / reference.image_path)
    except ImageReadError:
        raise _not_found(f"image of reference {reference_id} (its file is damaged or gone)") \
            from None
    return Response(png_bytes(tonemap_preview(image)), media_type="image/png")


@router.get("/sweeps/{sweep_id}", response_model=SweepOut)
def get_sweep(sweep_id: RowId, store: StoreDep, settings: SettingsDep) -> SweepOut:
    return SweepOut.of(_found(store.get_sweep(sweep_id), f"sweep {sweep_id}"),
                       data_dir=settings.data_dir)


@router.get("/artifacts/{artifact_id}", response_class=FileResponse)
def get_artifact(artifact_id: RowId, store: StoreDep, settings: SettingsDep) -> FileResponse:
    """An artifact's file (EXR, PNG, NPZ) with its media type."""
    with store.session() as session:
        artifact = session.get(Artifact, artifact_id)
    if artifact is None:
        raise _not_found(f"artifact {artifact_id}")
    path = ArtifactStore(settings.artifacts_dir).path_of(artifact.path)
    if not path.is_file():
        raise _not_found(f"file for artifact {artifact_id} (it was deleted from disk)")
    return FileResponse(path, media_type=artifact.media_type,
                        filename=f"{artifact.kind}-{artifact.id}{path.suffix}")


@router.get("/scenes", response_model=list[SceneOut])
def list_scenes() -> list[SceneOut]:
    """The built-in scenes (XML scenes are given by path in a spec)."""
    return [SceneOut(name=name, description=describe(name)) for name in builtin_names()]
