"""Work estimates of jobs: what a submission may cost before anything runs.

A job's work is counted in *path samples* (pixels x samples per pixel): a
render is ``pixels x spp x frames x seeds``, plus its reference's ``pixels x
spp`` if that reference is not stored yet; a sweep is the sum over its stages
(jobs/execution/graph.py) and its own last step. The estimate is an upper bound of the
sampling and training (a reference with a ``rel_stderr`` target may stop early),
good enough to refuse what
no service should accept (``Settings.max_job_work``) and to give a job without
an explicit ``--job-timeout`` a timeout of its size (:func:`default_timeout_s`).

``artifact_bytes`` estimates the files a job writes (uncompressed RGB float32
EXRs: images, and a run's relative-bias and relative-variance maps; PNG previews,
cache weights), for the disk limit ``Settings.max_data_bytes``.
Each part also counts its frames (or reference passes) and its renders (each with
its own start-up): what a job's *time* depends on besides its samples, used by
jobs/execution/timecost.py to bound jobs in seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sqlalchemy import func, select

from jobs.execution.graph import Stage, sweep_stages
from jobs.execution.method_work import FrameWork, frame_work
from jobs.protocol.spec import ReferenceSpec, RenderSpec, SweepSpec
from jobs.protocol.versions import reference_estimator_version
from jobs.record.config import DATABASE_FILENAME, Settings
from jobs.record.models import Artifact, Reference
from jobs.record.reproduction_folders import reproduction_bytes
from jobs.record.store import Store
from jobs.record.usage import distinct_file_bytes
from jobs.sweeps.snapshots import V1_PASSES
from metrics import METRIC_VERSION
from renderers.methods import METHODS, MethodParams, equal_time_pairs

#: Bytes per pixel of a stored image: RGB float32 (an upper bound; EXRs compress).
IMAGE_BYTES_PER_PIXEL = 12
#: Bytes per pixel of a PNG preview or error map (RGB 8 bit, uncompressed).
PREVIEW_BYTES_PER_PIXEL = 3
#: Per-pixel maps a run of 2+ seeds stores beside its images: relative bias and
#: relative variance over the seeds (RGB float32 EXRs, like an image).
PIXEL_MAPS = 2
#: A trained cache's stored weights (.npz), a rough allowance per snapshot.
SNAPSHOT_WEIGHTS_BYTES = 16 << 20


@dataclass
class WorkEstimate:
    """Path samples a job renders (``samples``) and the bytes it may store; per part,
    its samples, frames (or passes) and renders."""

    samples: int = 0
    artifact_bytes: int = 0
    parts: dict[str, int] = field(default_factory=dict)   # samples by what renders them
    frames: dict[str, int] = field(default_factory=dict)  # frames or passes, by part
    renders: dict[str, int] = field(default_factory=dict)  # renders (start-ups), by part

    def add(self, part: str, samples: int, artifact_bytes: int = 0, *, frames: int = 0,
            renders: int = 0) -> None:
        self.samples += samples
        self.artifact_bytes += artifact_bytes
        self.parts[part] = self.parts.get(part, 0) + samples
        self.frames[part] = self.frames.get(part, 0) + frames
        self.renders[part] = self.renders.get(part, 0) + renders


def pixel_maps(seeds: int) -> int:
    """How many per-pixel maps a run of ``seeds`` seeds stores (none with one seed)."""
    return PIXEL_MAPS if seeds >= 2 else 0


def _reference(estimate: WorkEstimate, pixels: int, reference: ReferenceSpec) -> None:
    estimate.add("reference", pixels * reference.spp, 2 * pixels * IMAGE_BYTES_PER_PIXEL,
                 frames=math.ceil(reference.spp / reference.spp_per_pass), renders=1)


def render_work(spec: RenderSpec, reference_stored: bool = False,
                params: MethodParams | None = None) -> WorkEstimate:
    """A render job: K seeds of ``frames`` frames at ``spp``, each frame and the
    pre-training frames as the method's parameters make them
    (jobs/execution/method_work.py); calibration probes and the largest candidate
    when the spp is calibrated to a time budget. ``params``: the job's parsed
    parameters (a queued job's: not validated again), else parsed from the spec."""
    estimate = WorkEstimate()
    pixels = spec.resolution ** 2
    if not reference_stored:
        _reference(estimate, pixels, spec.reference)
    spp = spec.spp
    method = METHODS.get(spec.method)
    if params is None and method is not None:
        params = method.params.model_validate(spec.params)

    def frame(spp: int) -> FrameWork:
        return frame_work(spec.method, params, pixels, spp)

    if spec.time_budget is not None and method is not None and method.knob is not None:
        knob, default = method.knob.name, list(method.knob.candidates)
        candidates = spec.time_budget.candidates or default
        per_candidate = [frame(c if knob == "spp" else spp) for c in candidates]
        budget = spec.time_budget
        estimate.add("calibration", math.ceil(budget.probe_frames * sum(
                         work.samples_per_frame for work in per_candidate)),
                     frames=budget.probe_frames * budget.rounds * len(candidates),
                     renders=len(candidates))
        if knob == "spp":
            spp = max(candidates)
    seed = frame(spp)
    frames = (spec.frames + seed.warm_frames) * spec.seeds
    frames_kept = spec.frames * spec.seeds if spec.keep_frames else 0
    estimate.add("seeds", math.ceil(seed.samples_per_frame * frames),
                 pixels * (IMAGE_BYTES_PER_PIXEL * (spec.seeds + frames_kept
                                                    + pixel_maps(spec.seeds))
                           + 2 * PREVIEW_BYTES_PER_PIXEL),
                 frames=frames, renders=spec.seeds)
    return estimate


def stage_work(spec: SweepSpec, task: dict[str, Any]) -> WorkEstimate:
    """One stage of a sweep (jobs.execution.graph.sweep_stages), or the sweep job's own last step
    (``{"stage": "sweep"}``: the 'NIRC equal time' series and the plots)."""
    estimate = WorkEstimate()
    pixels = spec.resolution ** 2
    point_bytes = pixels * (IMAGE_BYTES_PER_PIXEL * (spec.seeds + pixel_maps(spec.seeds))
                            + 2 * PREVIEW_BYTES_PER_PIXEL)
    match task["stage"]:
        case "reference":
            _reference(estimate, pixels, spec.reference)
        case "snapshot":
            estimate.add("caches", pixels * (spec.train_frames + spec.v1_spp),
                         SNAPSHOT_WEIGHTS_BYTES + pixels * IMAGE_BYTES_PER_PIXEL,
                         frames=spec.train_frames + V1_PASSES, renders=2)
        case "series":
            points = len(spec.eps or [])
            estimate.add("points", points * pixels * spec.frames * spec.seeds,
                         points * point_bytes, frames=points * spec.frames * spec.seeds,
                         renders=points * spec.seeds)
        case "parameter-point":
            estimate.add("points", pixels * (spec.train_frames + spec.frames) * spec.seeds,
                         point_bytes, frames=(spec.train_frames + spec.frames) * spec.seeds,
                         renders=spec.seeds)
        case "sweep":
            pairs = equal_time_pairs(spec.methods) if spec.kind == "eps" and spec.equal_time else []
            for _pair in pairs:
                points = len(spec.eps or [])
                candidates = len(spec.nc_candidates())
                probes = candidates * spec.probe_frames
                estimate.add("equal time", points * pixels * (probes + spec.frames * spec.seeds),
                             points * point_bytes,
                             frames=points * (probes * spec.calibration_rounds
                                              + spec.frames * spec.seeds),
                             renders=points * (candidates + spec.seeds))
    return estimate


def sweep_work(spec: SweepSpec, stages: list[Stage] | None = None) -> WorkEstimate:
    """A whole sweep: every stage and the sweep job's own step."""
    estimate = WorkEstimate()
    for stage in [*(stages if stages is not None else sweep_stages(spec)),
                  Stage("sweep", {"stage": "sweep"})]:
        part = stage_work(spec, stage.task)
        estimate.artifact_bytes += part.artifact_bytes
        for name, samples in part.parts.items():
            estimate.add(name, samples, frames=part.frames[name], renders=part.renders[name])
    return estimate


def default_timeout_s(estimate: WorkEstimate, settings: Settings) -> float:
    """A job's timeout from its size: start-up and JIT time plus its samples at the
    slowest rate the service is expected to sample (both settings)."""
    return settings.job_timeout_min_s + estimate.samples / settings.timeout_samples_per_s


def reference_stored(store: Store, scene: str, resolution: int, reference: ReferenceSpec,
                     max_depth: int) -> bool:
    """Whether a reference for these settings is stored (by scene name, as the loader
    names it: a built-in's name or an XML file's absolute path), so it need not be
    counted. An XML file edited since would be rendered again, uncounted."""
    settings = reference.settings(max_depth)
    name = scene
    if scene.lower().endswith(".xml"):
        try:
            name = str(Path(scene).expanduser().resolve())
        except (OSError, RuntimeError, ValueError):
            return False
    with store.session() as session:
        rows = session.scalars(select(Reference).where(
            Reference.scene_name == name, Reference.width == resolution,
            Reference.height == resolution,
            Reference.estimator_version == reference_estimator_version(settings.integrator),
            Reference.metric_version == METRIC_VERSION)).all()
    return any(row.settings == settings.to_json() for row in rows)


def data_bytes(store: Store, settings: Settings) -> int:
    """Bytes the data folder holds: the stored artifacts (each file once), the
    reference files, the stored scenes, the uploaded images, the stored reproductions
    (the command line's and the jobs') and the SQLite database file (if the database is
    one)."""
    with store.session() as session:
        distinct = select(Artifact.path, func.max(Artifact.bytes).label("bytes")) \
            .group_by(Artifact.path).subquery()
        total = int(session.scalar(select(func.coalesce(func.sum(distinct.c.bytes), 0))) or 0)
    if settings.references_dir.is_dir():
        total += sum(entry.stat().st_size for entry in settings.references_dir.iterdir()
                     if entry.is_file())
    for folder in (settings.scenes_dir, settings.uploaded_images_dir):
        if folder.is_dir():
            total += distinct_file_bytes(folder.rglob("*"))
    total += reproduction_bytes(settings)
    database = settings.data_dir / DATABASE_FILENAME
    for path in (database, database.with_name(database.name + "-wal")):
        if str(settings.database_url).startswith("sqlite") and path.is_file():
            total += path.stat().st_size
    return total
