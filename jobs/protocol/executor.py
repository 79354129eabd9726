"""The executor: the one place that joins rendering, metrics and storage.

The CLI (embedded) and the service workers (distributed) both run a job by
calling :func:`execute`. A job renders its method K times with independent
seeds, compares each accumulated image with the converged reference, reduces
the K results to rBias^2 / rVar / MRSE with a confidence interval (less the
reference's own noise floor), adds rBias^2 / rVar per cache from each seed's
frames, writes the artifacts, and stores the run with its provenance in one
transaction.
"""

from __future__ import annotations

import gc
import sys
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from jobs.protocol.animation import execute_animated
from jobs.protocol.calibration import calibrate_job
from jobs.protocol.job import RenderJob
from jobs.protocol.provenance import git_branch, git_commit, library_versions
from jobs.protocol.quality import finite_record, judge_run
from jobs.protocol.references import LoadedReference, get_or_render_reference
from jobs.protocol.results import RunResultDetail
from jobs.protocol.scene_store import load_spec_scene
from jobs.protocol.spec import RenderSpec
from jobs.protocol.versions import versions_of
from jobs.record.artifacts import (
    RELATIVE_BIAS_MAP,
    RELATIVE_VARIANCE_MAP,
    ArtifactStore,
    artifact_record,
    encode_image,
)
from jobs.record.config import Settings
from jobs.record.store import Store
from metrics.bias_intervals import per_cache_headline
from metrics.checks import MetricError
from metrics.denoised import (
    ACCUMULATED_FRAMES,
    DENOISER_KEY,
    denoised_metrics,
    denoiser_provenance,
)
from metrics.errors import (
    bias_variance,
    image_metrics,
    mrse,
    per_cache_bias_variance,
    relative_squared_error_map,
)
from metrics.imageio import write_exr, write_png
from metrics.pixel_maps import relative_bias_variance_maps
from metrics.preview import error_map_preview, tonemap_preview
from metrics.quality import withhold
from metrics.registry import METRICS, Aggregate, per_seed_values, seed_mean
from metrics.residual_variance import relative_residual_variance
from metrics.statistics import RunningMoments, interval_or_reason
from renderers.backend import device_info, init_backend
from renderers.denoise_features import FEATURE_SPP, render_features
from renderers.methods import check_applies, get_method
from renderers.methods.base import FrameHooks, OnFrame, RenderOutput
from renderers.scenes.loader import animated
from renderers.timing import pooled

#: progress(stage, done, total): stage is 'reference' or 'seed k/K'.
Progress = Callable[[str, int, int], None]


@dataclass
class RunSummary:
    """What a finished job reports (also stored in the database)."""

    run_id: int
    spec: RenderSpec
    scene_fingerprint: str
    reference: dict[str, Any]
    metrics: dict[str, Any]
    per_seed: list[dict[str, Any]]
    timings: dict[str, Any]
    path_stats: dict[str, Any]
    device: dict[str, Any]
    quality: dict[str, Any]
    estimator_version: int
    metric_version: int
    result: RunResultDetail     # the stored run as users see it (jobs.protocol.results)
    files: dict[str, str] = field(default_factory=dict)   # set where it is exported (jobs.views.export)
    reused: bool = False        # a run stored earlier (:func:`find_same_run`), not rendered now

    @classmethod
    def of_stored(cls, run: Any, spec: RenderSpec, settings: Settings, *,
                  reference_rendered_now: bool = False, reused: bool = False) -> RunSummary:
        """The summary of the stored ``run`` (loaded as ``Store.get_run`` loads it) of
        ``spec``: what a render that made it reports, and what one that reuses it reports."""
        reference = run.reference
        reference_info = {} if reference is None else {
            "id": reference.id, "key": reference.key, "spp": reference.spp,
            "max_depth": reference.max_depth, "integrator": reference.integrator,
            "split_half": reference.split_half,
            "path": str(settings.references_dir / reference.image_path),
            "rendered_now": reference_rendered_now}
        return cls(
            run_id=run.id, spec=spec,
            scene_fingerprint=run.scene_fingerprint, reference=reference_info,
            metrics=run.metrics, per_seed=[s.metrics for s in run.seed_results],
            timings=run.timings, path_stats=run.path_stats, device=run.device,
            quality=run.quality, estimator_version=run.estimator_version,
            metric_version=run.metric_version, result=RunResultDetail.of(run), reused=reused)

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["spec"] = self.spec.model_dump(mode="json")
        data["result"] = self.result.model_dump(mode="json")
        return data


def _seed_artifacts(store: ArtifactStore, scratch: Path, seed: int, image: np.ndarray,
                    reference: LoadedReference, eps: float, previews: bool) -> list[dict]:
    artifacts = [artifact_record(store, encode_image(write_exr, image, scratch / "img.exr"), "image",
                           ".exr", "image/x-exr", seed)]
    if previews:
        error_map = relative_squared_error_map(image, reference.mean, eps)
        artifacts += [
            artifact_record(store, encode_image(write_png, tonemap_preview(image), scratch / "p.png"),
                      "preview", ".png", "image/png", seed),
            artifact_record(store, encode_image(write_png, error_map_preview(error_map), scratch / "e.png"),
                      "error_map", ".png", "image/png", seed),
        ]
    return artifacts


def _pixel_map_artifacts(store: ArtifactStore, scratch: Path, images: list[np.ndarray],
                         reference: LoadedReference, eps: float) -> list[dict]:
    """The run's relative-bias and relative-variance maps over its seeds (EXR, float32;
    metrics.pixel_maps), for the dashboard's comparison view: none with one seed."""
    if len(images) < 2:
        return []
    bias, variance = relative_bias_variance_maps(images, reference.mean, eps)
    return [artifact_record(store, encode_image(write_exr, image, scratch / "m.exr"), kind,
                            ".exr", "image/x-exr")
            for kind, image in ((RELATIVE_BIAS_MAP, bias), (RELATIVE_VARIANCE_MAP, variance))]


def mean_over_seeds(stats: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean of every numeric statistic over seeds. A nested dict is a histogram
    (``cache_depth_fractions``): its mean is over the union of the seeds' bins,
    a bin a seed never hit counting 0 for that seed."""
    result: dict[str, Any] = {}
    for key, first in stats[0].items():
        values = [s.get(key) for s in stats]
        if isinstance(first, dict):
            histograms = [v or {} for v in values]
            bins = dict.fromkeys(b for histogram in histograms for b in histogram)
            result[key] = {b: float(np.mean([h.get(b, 0.0) for h in histograms])) for b in bins}
        elif isinstance(first, int | float):
            result[key] = float(np.mean([v for v in values if v is not None]))
    return result


def aggregate(per_seed: list[dict[str, Any]], images: list[np.ndarray],
              reference: LoadedReference, eps: float, frame_seconds: float,
              frame_moments: Sequence[RunningMoments] | None = None,
              correlated_frames: bool = False) -> dict[str, Any]:
    """Reduce K per-seed results to each metric of metrics.registry.METRICS by its
    aggregate form: rBias^2/rVar over seeds and mean MRSE with its CI, less the
    reference floor (metrics.errors.bias_variance), the per-cache statistics of
    :func:`per_cache_metrics` (the headline rBias^2 of a method whose seeds each train
    a cache, which names it under ``method_stats['caches']``:
    metrics.bias_intervals.per_cache_headline), means over seeds, then the derived values.

    A per-seed value is None when that image had no finite pixel at all; such
    seeds are left out of the means (the quality flag already reports them).
    """
    metrics: dict[str, Any] = {"k": len(images), "eps": eps}
    # ---- Joint passes over the K renders (MEAN_CI, BIAS_VARIANCE and PER_CACHE entries) ----
    if len(images) >= 2:
        metrics.update(bias_variance(np.stack(images), reference.mean, eps,
                                     ref_variance=reference.variance))
    else:
        metrics.update({m.key: per_seed[0][m.seed_key] for m in METRICS
                        if m.aggregate is Aggregate.MEAN_CI and m.seed_key in per_seed[0]})
        metrics.update({key: per_seed[0][key] for key in
                        ("mrse_corrected", "ref_floor", "ref_floor_ratio_mrse", "warnings")})
    metrics.update(mean_ci_of_seed_values(per_seed, metrics))
    metrics.update(per_cache_metrics(frame_moments, reference, eps, correlated_frames))
    # A cache trained per seed: rBias^2 is the mean over the caches, which cannot cancel.
    if all("caches" in (s.get("method_stats") or {}) for s in per_seed):
        metrics.update(per_cache_headline(metrics))
    # ---- Means over seeds (MEAN entries; none where no seed computed it: a metric of a
    # run option the run did not ask for, such as the denoised errors) ----
    for metric in METRICS:
        if metric.aggregate is Aggregate.MEAN and any(metric.seed_key in s for s in per_seed):
            metrics[metric.key] = seed_mean(metric, per_seed)
    metrics["seconds_per_frame"] = frame_seconds
    # ---- Values derived from the aggregates above (DERIVED entries) ----
    for metric in METRICS:
        if metric.aggregate is Aggregate.DERIVED:
            metrics[metric.key] = metric.derive(metrics)
    return metrics


def mean_ci_of_seed_values(per_seed: list[dict[str, Any]],
                           metrics: dict[str, Any]) -> dict[str, Any]:
    """MEAN_CI metrics that no joint pass gave (V_rel): the seeds' values
    (``<seed_key>_per_seed``), their mean and its 95 % interval on the log scale
    (metrics.statistics.interval_or_reason); only where some seed has a value."""
    result: dict[str, Any] = {}
    for metric in METRICS:
        if (metric.aggregate is not Aggregate.MEAN_CI or metric.key in metrics
                or not any(metric.seed_key in s for s in per_seed)):
            continue
        values = [s[metric.seed_key] for s in per_seed if s.get(metric.seed_key) is not None]
        ci, note = interval_or_reason(values)
        result.update({f"{metric.seed_key}_per_seed": values,
                       metric.key: float(np.mean(values)) if values else None,
                       metric.ci_key: list(ci) if ci else None,
                       f"{metric.seed_key}_ci_note": note})
    return result


#: Keys of the per-cache statistics (metrics.errors.per_cache_bias_variance).
PER_CACHE_KEYS = (*(f"{name}_per_cache{suffix}" for name in ("rbias2", "rvar")
                    for suffix in ("", "_mean", "_std", "_min", "_max")),
                  "per_cache_frames", "per_cache_excluded_pixels")


def per_cache_metrics(frame_moments: Sequence[RunningMoments] | None,
                      reference: LoadedReference, eps: float,
                      correlated_frames: bool = False) -> dict[str, Any]:
    """rBias^2 / rVar of each seed's cache from its own frames, with mean and spread.

    When they cannot be computed (no frame statistics collected, fewer than 2
    frames per seed, no finite pixel) or would be wrong (``correlated_frames``: a
    method whose frames share samples, ``Method.correlated_frames``) every key is
    None and ``per_cache_unavailable`` says why.
    """
    try:
        if correlated_frames:
            raise MetricError(
                "this method's frames share samples (temporal reuse), so the spread of "
                "a seed's frames understates the variance of their mean and the "
                "difference would be reported as bias; compare seeds instead (rbias2)")
        if not frame_moments:
            raise MetricError("no per-frame statistics were collected for this run")
        return {**per_cache_bias_variance([m.estimate() for m in frame_moments],
                                          reference.mean, eps, reference.variance),
                "per_cache_unavailable": None}
    except MetricError as err:
        return {**dict.fromkeys(PER_CACHE_KEYS),
                "per_cache_unavailable": f"per-cache rBias^2/rVar unavailable: {err}"}


def frame_moments_hook(moments: RunningMoments) -> OnFrame:
    """A FrameHooks.on_frame that adds every frame to ``moments`` (per-cache statistics)."""
    def add(_index: int, frame: np.ndarray, _accumulated: np.ndarray) -> None:
        moments.add(frame)

    return add


def last_frames_hook(kept: deque[np.ndarray]) -> OnFrame:
    """A FrameHooks.on_frame that keeps the frames in ``kept`` (a bounded deque: the last
    ones; the frame loop hands each frame over as a new array)."""
    def keep(_index: int, frame: np.ndarray, _accumulated: np.ndarray) -> None:
        kept.append(frame)

    return keep


def chain(*hooks: OnFrame) -> OnFrame:
    """One FrameHooks.on_frame that calls ``hooks`` in order."""
    def call_all(index: int, frame: np.ndarray, accumulated: np.ndarray) -> None:
        for hook in hooks:
            hook(index, frame, accumulated)

    return call_all


@dataclass
class SeedRender:
    """One seed's render with what :func:`store_run` needs of it besides the image."""

    output: RenderOutput
    convergence: dict[str, Any]     # ConvergenceTracker.result()
    moments: RunningMoments         # per-pixel moments of its frames (per-cache rBias^2/rVar)
    last_frames: list[np.ndarray]   # its last ACCUMULATED_FRAMES frames (denoised metrics)


def render_seed(render: Callable[[FrameHooks], RenderOutput], reference: np.ndarray, eps: float,
                *, keep_frames: bool = False, warmup: bool = True,
                progress: Callable[[int, int], None] | None = None,
                first_frame: int = 0) -> SeedRender:
    """Run ``render(hooks)`` (one seed's frame loop) with the error-over-frames tracker and
    the frame moments and the last frames kept: the one frame loop of every stored run
    (render jobs, sweep points). ``first_frame``: where the seed's frames start in the run's
    schedule of wall and kernel frames (FrameHooks.first_frame)."""
    tracker = ConvergenceTracker(reference, eps)
    moments = RunningMoments()
    last: deque[np.ndarray] = deque(maxlen=ACCUMULATED_FRAMES)
    gc.collect()   # the previous seed's objects, before this seed's frozen calls (prepare)
    output = render(FrameHooks(keep_frames=keep_frames, warmup=warmup, progress=progress,
                               on_frame=chain(tracker, frame_moments_hook(moments),
                                              last_frames_hook(last)),
                               first_frame=first_frame))
    return SeedRender(output, tracker.result(), moments, list(last))


class ConvergenceTracker:
    """Error of every frame and of the running mean against the reference (Fig. 10 of
    the NIRC paper: how the error falls as the cache trains), as a FrameHooks.on_frame.

    Non-finite MRSE values (a frame with NaN/Inf pixels) are stored as None.
    """

    def __init__(self, reference: np.ndarray, eps: float) -> None:
        self.reference = reference
        self.eps = eps
        self.frame_mrse: list[float | None] = []
        self.accumulated_mrse: list[float | None] = []

    def __call__(self, _index: int, frame: np.ndarray, accumulated: np.ndarray) -> None:
        self.frame_mrse.append(_finite_or_none(mrse(frame, self.reference, self.eps)))
        self.accumulated_mrse.append(_finite_or_none(mrse(accumulated, self.reference, self.eps)))

    def result(self) -> dict[str, list[float | None]]:
        return {"frame_mrse": self.frame_mrse, "accumulated_mrse": self.accumulated_mrse}


def _finite_or_none(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


#: Jobs after which the collection is full even though no earlier scene outlived its job.
FULL_EVERY = 16


class JobCollector:
    """Collects before each job what the earlier jobs of this process left
    (docs/timing.md, "The width rule").

    A render process serves several jobs. Dr.Jit walks the objects of every scene alive, so
    a scene an earlier job left in a reference cycle, freed by a collection in the middle of
    a later job's frames, changes what every frozen call walks and makes each record again.
    So what earlier jobs left is collected before a job loads its scene, and what is alive
    once the scene and its reference are loaded (modules, the scene) is frozen out of the
    collector's generations (``gc.freeze``): each seed's collection then walks only what the
    job made since.

    A full collection (``gc.unfreeze`` + ``gc.collect``) walks the process's whole heap:
    0.10-0.14 s per job with ~133k objects alive (measured in one process running small
    jobs), half of what a 4x4 job costs. It is needed where an earlier job's scene outlived
    its job, the one object whose late freeing changes frozen calls. So the collector keeps
    the last job's Mitsuba scene and, before the next job, asks whether anything but itself
    still holds it (its reference count): if so, or every :data:`FULL_EVERY` jobs (to bound
    what else earlier jobs left in cycles), the collection is full; otherwise it collects
    what was made since the last freeze (under a millisecond) and the scene, held by nothing
    else, is freed by its reference count.
    """

    def __init__(self) -> None:
        self._scene: Any = None
        self._jobs = 0
        self._since_full = 0
        self.full_collections = 0

    def before_job(self) -> bool:
        """Collect what earlier jobs left (the class docstring); True when it was full."""
        self._jobs += 1
        if self._jobs == 1:     # nothing is frozen yet: this collection is full anyway
            gc.collect()
            return True
        scene, self._scene = self._scene, None
        # One reference is ``scene``, one getrefcount's argument: any more is a holder.
        held_elsewhere = scene is not None and sys.getrefcount(scene) > 2
        del scene
        self._since_full += 1
        if held_elsewhere or self._since_full >= FULL_EVERY:
            gc.unfreeze()
            gc.collect()
            self._since_full = 0
            self.full_collections += 1
            return True
        gc.collect()
        return False

    def after_load(self, scene: Any) -> None:
        """Keep the job's Mitsuba ``scene`` for the next job's question and freeze what is
        alive now out of the collector's generations."""
        self._scene = scene
        gc.freeze()

    def release(self) -> None:
        """Let go of what the last job kept: its scene, and what it froze out of the
        collector's generations (collected now). For a process that runs other renders
        between jobs (tests, scripts): a scene left alive makes every later call over
        the emitters, shapes or BSDFs trace its objects too (Dr.Jit traces every
        registered instance), so later renders compile other kernels and run slower
        (measured: a Cornell box reference at 16x16, 0.8 s alone, 33-49 s with 20 other
        scenes alive). The next job collects in full, as the first one does."""
        if self._scene is None and gc.get_freeze_count() == 0:
            return
        self._scene = None
        self._jobs = 0
        gc.unfreeze()
        gc.collect()


#: The collector of this process's jobs (:func:`prepare`).
COLLECTOR = JobCollector()


@dataclass
class Prepared:
    """What every job of a scene needs before rendering: backend, scene, reference."""

    scene: Any
    reference: LoadedReference
    device: dict[str, Any]
    started: datetime


def prepare(job: RenderJob, store: Store, settings: Settings,
            progress: Progress | None = None, *, check_method: bool = False) -> Prepared:
    """Initialise the backend, load the scene and get (or render) its reference.

    ``check_method``: refuse (NotApplicable) a method that does not apply to the scene
    before its reference is got: the scene's features come with loading it, while a
    reference not stored yet can take minutes to render."""
    init_backend()
    # What earlier jobs of this process left (their scenes, held by reference cycles) is
    # freed now, not by a collection in the middle of this job's frames: every frozen
    # call walks the objects of all scenes alive, so a scene freed then made each frozen
    # function record again (measured: 8 recordings at once, nirc-nvc-env after pt).
    COLLECTOR.before_job()
    spec = job.spec
    scene = load_spec_scene(spec.scene, spec.resolution, settings)
    if spec.animation is not None:
        scene = animated(scene, spec.animation)
    if check_method:
        check_applies(job.method, scene.features)
    started = datetime.now(UTC)
    reference = get_or_render_reference(
        store, settings.references_dir, scene, spec.reference.settings(job.max_depth),
        progress=(lambda done, total: progress("reference", done, total)) if progress else None)
    # What is alive now (modules, this scene, its reference) lives until the next job's
    # collection above: moved out of the collector's generations, it is not walked again by
    # each seed's collection (render_seed), which then costs what the seeds left, not the
    # process's whole heap (0.18 s per seed with ~200k objects alive, measured).
    COLLECTOR.after_load(scene.scene)
    return Prepared(scene=scene, reference=reference, device=device_info(), started=started)


def replaced_settings(file_settings: dict[str, Any], spec: RenderSpec, resolution: Any,
                      max_depth: int) -> list[str]:
    """What the scene file sets (LoadedScene.file_settings) that this run replaced, one
    line each, e.g. "film 1920x1080 -> 64x64 (the run's resolution)"."""
    lines = []
    film = file_settings.get("film")
    if film and list(film) != list(resolution):
        lines.append(f"film {'x'.join(map(str, film))} -> {resolution[0]}x{resolution[1]} "
                     "(the run's resolution)")
    if "integrator" in file_settings:
        lines.append(f"integrator '{file_settings['integrator']}' -> {spec.method}'s own")
    if "max_depth" in file_settings and file_settings["max_depth"] != max_depth:
        lines.append(f"max_depth {file_settings['max_depth']} -> {max_depth} (the run's)")
    if "spp" in file_settings and file_settings["spp"] != spec.spp:
        lines.append(f"sampler {file_settings['spp']} spp -> {spec.spp} spp x {spec.frames} "
                     "frames")
    return lines


def store_run(job: RenderJob, prepared: Prepared, seeds: Sequence[SeedRender], store: Store,
              settings: Settings, *, idempotency_key: str | None = None,
              extra: dict[str, Any] | None = None) -> RunSummary:
    """Evaluate K seeds' renders (:func:`render_seed`) against the reference and store them
    as one run.

    ``extra`` is merged into the run's metrics (e.g. a calibration record, or a
    sweep point's threshold and mask coverage) and stored with its parameters.
    The seeds' frame moments (16 bytes per pixel-channel each) give the per-cache
    rBias^2 / rVar.
    The run's quality verdict (jobs.protocol.quality) is stored with it, and the metrics
    the verdict withholds are stored as None, per seed and aggregated. A NaN or
    infinite metric, statistic or loss is stored as None too, and the verdict names it
    (``quality['nonfinite_values']``).
    """
    scene, reference, device = prepared.scene, prepared.reference, prepared.device
    spec = job.spec
    param_json = job.params.model_dump(mode="json")
    artifacts_store = ArtifactStore(settings.artifacts_dir)
    scratch = settings.data_dir / "tmp"
    scratch.mkdir(parents=True, exist_ok=True)
    outputs = [rendered.output for rendered in seeds]
    # The denoiser's features, once per run (renderers.denoise_features).
    features = render_features(scene.scene) if spec.denoised else None
    per_seed, artifacts = [], []
    for index, (output, rendered) in enumerate(zip(outputs, seeds, strict=True)):
        seed, curve = spec.seed_start + index, rendered.convergence
        values = image_metrics(output.accumulated, reference.mean, eps=spec.eps,
                               flip_exposures=reference.flip_exposures,
                               ref_variance=reference.variance)
        values.update(per_seed_values(output.accumulated, reference.mean))
        if output.residual_variance is not None:
            values["v_rel"] = relative_residual_variance(output.residual_variance,
                                                         reference.mean, spec.eps)
        if features is not None:
            values.update(denoised_metrics(rendered.last_frames, reference.mean, spec.eps,
                                           reference.flip_exposures, features))
        values["seconds_per_frame"] = output.timings["frame_median_s"]
        per_seed.append({"seed": seed, **values, "path_stats": output.path_stats,
                         "method_stats": output.method_stats, "convergence": curve})
        artifacts += _seed_artifacts(artifacts_store, scratch, seed, output.accumulated,
                                     reference, spec.eps, previews=index == 0)
        # Per-frame images (``keep_frames``), named frame_<seed>_<index> when exported.
        for number, frame in enumerate(output.frames or []):
            artifacts.append(artifact_record(artifacts_store,
                                       encode_image(write_exr, frame, scratch / "f.exr"),
                                       f"frame{number:05d}", ".exr", "image/x-exr", seed))

    artifacts += _pixel_map_artifacts(artifacts_store, scratch,
                                      [o.accumulated for o in outputs], reference, spec.eps)
    seed_timings = [output.timings for output in outputs]
    # One statistic over every timed frame of every seed: the frame time, the stages
    # and the breakdown of the median frame (renderers.timing.pooled).
    timings = pooled(seed_timings)
    frame_seconds = timings["frame_median_s"]
    timings["seconds_per_frame"] = frame_seconds
    metrics = aggregate(per_seed, [o.accumulated for o in outputs], reference, spec.eps,
                        frame_seconds, [rendered.moments for rendered in seeds],
                        get_method(spec.method).correlated_frames)
    if features is not None:
        # The means over seeds leave out a seed that was not denoised (its denoised_note
        # says why): how many were is said with the denoiser.
        metrics[DENOISER_KEY] = {**denoiser_provenance(), "feature_spp": FEATURE_SPP,
                                 "seeds_denoised": sum(s["denoised_note"] is None
                                                       for s in per_seed)}
    metrics.update(extra or {})
    metrics, per_seed, nonfinite = finite_record(metrics, per_seed)
    path_stats = mean_over_seeds([s["path_stats"] for s in per_seed])
    verdict, quality = judge_run([o.accumulated for o in outputs], reference.mean,
                                 scene.features.emitter_count,
                                 [o.method_stats for o in outputs], reference.variance,
                                 nonfinite)
    metrics = withhold(metrics, verdict.withheld)
    per_seed = [withhold(s, verdict.withheld) for s in per_seed]
    versions = versions_of(spec.method)
    replaced = replaced_settings(scene.file_settings, spec, scene.resolution, job.max_depth)

    run = store.add_run(
        {
            "created_at": prepared.started, "finished_at": datetime.now(UTC),
            "status": "succeeded", "scene_name": scene.name,
            "scene_fingerprint": scene.fingerprint, "method": spec.method,
            "params": {**param_json, "spec": spec.model_dump(mode="json"), **(extra or {}),
                       **({"scene_overrides": replaced} if replaced else {})},
            "width": scene.resolution[0], "height": scene.resolution[1], "spp": spec.spp,
            "frames": spec.frames, "seeds": len(outputs), "reference_id": reference.id,
            "metrics": metrics, "timings": timings, "path_stats": path_stats,
            "device": device, "device_key": device["device_key"],
            "versions": library_versions(), "git_commit": git_commit(), "git_branch": git_branch(),
            "quality": quality,
            "idempotency_key": idempotency_key, **versions,
        },
        [{"seed": s["seed"], "metrics": s, "timings": t}
         for s, t in zip(per_seed, seed_timings, strict=True)],
        artifacts,
    )
    return RunSummary.of_stored(run, spec, settings,
                                reference_rendered_now=reference.rendered_now)


def find_same_run(spec: RenderSpec, prepared: Prepared, store: Store) -> Any:
    """The newest stored run of exactly ``spec`` on this scene (same fingerprint), against
    the same reference, by the same commit, today's estimator and metric versions and on
    this device (loaded as ``Store.get_run`` loads it), or None. Nothing matches when the
    commit is unknown or has uncommitted changes ('-dirty'): the code that made a run
    could not be told apart from today's."""
    commit = git_commit()
    if commit == "unknown" or commit.endswith("-dirty"):
        return None
    wanted = spec.model_dump(mode="json")
    versions = versions_of(spec.method)
    for run in store.list_runs(prepared.scene.name, spec.method,
                               prepared.device["device_key"], git_ref=commit):
        if (run.status == "succeeded" and run.git_commit == commit
                and run.scene_fingerprint == prepared.scene.fingerprint
                and run.reference_id == prepared.reference.id
                and run.estimator_version == versions["estimator_version"]
                and run.metric_version == versions["metric_version"]
                and run.params.get("spec") == wanted):
            return store.get_run(run.id)
    return None


def execute(
    job: RenderJob,
    store: Store,
    settings: Settings,
    progress: Progress | None = None,
    idempotency_key: str | None = None,
    reuse: bool = False,
) -> RunSummary:
    """Run ``job`` to completion and store the result; see the module docstring. A method
    that does not apply to the scene is refused (NotApplicable) before anything renders.

    With ``reuse``, a run of the same spec stored earlier (:func:`find_same_run`) is
    returned (``reused`` set) instead of rendering.

    With a ``time_budget`` the spp (pt) or N_c (biased nirc) is first calibrated
    to it on this device (jobs.protocol.calibration); the run stores the calibrated spec
    and the calibration record (metrics['calibration']).

    ``idempotency_key`` (e.g. a sweep point's key) is stored with the run; a
    second run under the same key raises ``DuplicateKeyError``.
    """
    method = get_method(job.method)
    prepared = prepare(job, store, settings, progress, check_method=True)
    stored = find_same_run(job.spec, prepared, store) if reuse else None
    if stored is not None:
        return RunSummary.of_stored(stored, job.spec, settings, reused=True)
    extra: dict[str, Any] = {}
    if job.spec.time_budget is not None:
        if progress:
            progress("calibration", 0, 1)
        job, calibration = calibrate_job(job, prepared.scene, prepared.device["device_key"])
        extra["calibration"] = calibration.to_json()
        if progress:
            progress("calibration", 1, 1)
    if prepared.scene.animation is not None:
        return execute_animated(job, prepared, store, settings, progress, idempotency_key, extra)
    spec, params = job.spec, job.params
    param_json = params.model_dump(mode="json")
    rendered = []
    for seed in range(spec.seed_start, spec.seed_start + spec.seeds):
        label = f"seed {seed + 1 - spec.seed_start}/{spec.seeds}"
        if progress:    # the stage starts (a cache's training comes before its frames)
            progress(label, 0, spec.frames)
        rendered.append(render_seed(
            lambda hooks, seed=seed: method.render(
                prepared.scene, params,
                seed_parts=(prepared.scene.fingerprint, spec.method, param_json, spec.spp, seed),
                spp=spec.spp, frames=spec.frames, hooks=hooks),
            prepared.reference.mean, spec.eps, keep_frames=spec.keep_frames,
            progress=(lambda done, total, label=label: progress(label, done, total))
            if progress else None, first_frame=(seed - spec.seed_start) * spec.frames))
    return store_run(job, prepared, rendered, store, settings,
                     idempotency_key=idempotency_key, extra=extra)
