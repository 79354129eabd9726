"""Converged caches and their cache-at-v1 images, computed once and reused.

The adaptive equal-bias protocol (NIRC paper Sec. 6.3) needs, for every seed
of a caching method, (a) a trained cache and (b) the converged image of
terminating every path into that cache at its first vertex v1, from which
the per-pixel relative bias, and so the v1 mask of every eps, follows. Both
are pure functions of (scene, resolution, method parameters, training
frames, v1 samples, seed), which is the snapshot's content key: a snapshot
is computed once, stored (weights .npz + v1 image .exr + the v1 image's
per-pixel variance .exr + statistics), and reused by every eps of a sweep and
by every later sweep. A stored snapshot without the variance (made before it
was kept) is made again when loaded.

Training is the method's own online loop (renderers/methods/cached.py): each
training frame also renders one 1-spp frame with the cache at v1 everywhere,
so the snapshot records how the error of that image falls while the cache
trains (the convergence curve of the paper's Fig. 10). The v1 image is then
rendered with the frozen cache, in independent passes whose spread gives the
variance the bias maps subtract (metrics/bias_maps.py).
"""

from __future__ import annotations

import io
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np

from jobs.protocol.executor import ConvergenceTracker, Prepared
from jobs.protocol.versions import versions_of
from jobs.record.artifacts import ArtifactStore, artifact_record, encode_image
from jobs.record.config import Settings
from jobs.record.store import DuplicateKeyError, Store
from metrics.imageio import ImageReadError, read_exr, write_exr
from metrics.statistics import RunningMoments
from renderers.methods.base import FrameHooks
from renderers.methods.cached import CacheTrainingParams, render_with_cache
from renderers.reference import render_passes
from renderers.seeding import derive_seed, digest

#: Lanes per pass of the v1 render (bounds the memory of one wavefront).
V1_PASS_LANES = 1 << 22
#: Passes of the v1 render (its variance has V1_PASSES - 1 degrees of freedom).
V1_PASSES = 16


@dataclass
class Snapshot:
    """A loaded snapshot: the cache weights, the converged cache-at-v1 image and the
    per-pixel variance of that image (of the mean, from its independent passes)."""

    key: str
    id: int
    weights: dict[str, np.ndarray]
    v1_image: np.ndarray
    v1_variance: np.ndarray
    stats: dict[str, Any]
    created_now: bool


#: build(scene, params, seed) -> (render integrator, training integrator, cache).
Builder = Callable[[Any, Any, int], tuple[Any, Any, Any]]


def snapshot_key(prepared: Prepared, method: str, params: CacheTrainingParams, seed: int,
                 train_frames: int, v1_spp: int) -> str:
    """Content address of a snapshot (the reference is part of it: the curve uses it) under
    today's estimator and metric versions."""
    return digest("cache-snapshot", prepared.scene.fingerprint, list(prepared.scene.resolution),
                  method, params.model_dump(mode="json"), seed, train_frames, v1_spp,
                  prepared.reference.key, versions_of(method), length=32)


def get_or_make_snapshot(
    store: Store, settings: Settings, prepared: Prepared, method: str, build: Builder,
    params: CacheTrainingParams, seed: int, *, train_frames: int, v1_spp: int, eps: float,
    progress: Callable[[int, int], None] | None = None,
) -> Snapshot:
    """Load the snapshot of (method, params, seed), training and storing it if missing.

    ``params`` must describe the adaptive termination with no mask (every path
    terminates into the cache at v1 where it may). A stored snapshot whose
    files are damaged is made again.
    """
    key = snapshot_key(prepared, method, params, seed, train_frames, v1_spp)
    row = store.find_snapshot(key)
    if row is not None:
        try:
            return _load(row, settings)
        except (ImageReadError, OSError, ValueError, KeyError):
            pass  # damaged files: make it again below (a new row would clash: reuse it)
    integrator, trainer, cache = build(prepared.scene, params,
                                       derive_seed(key, "cache"))
    started = datetime.now(UTC)
    tracker = ConvergenceTracker(prepared.reference.mean, eps)
    training = render_with_cache(
        prepared.scene, params.model_copy(update={"pretrain_frames": 0}), integrator, trainer,
        cache, seed_parts=(key, "train"), spp=1, frames=train_frames,
        hooks=FrameHooks(on_frame=tracker, progress=progress))
    v1_image, v1_variance, v1_info = render_v1(prepared.scene, integrator, v1_spp,
                                               derive_seed(key, "v1"))
    weights = cache.inference_parameters()
    stats = {
        "convergence": tracker.result(),
        "train_seconds_per_frame": training.timings["frame_median_s"],
        "train_frames_s": sum(sum(f.values()) for f in training.timings["per_frame"]),
        "train_stages": training.timings["stages"],
        "warmup_s": training.timings["warmup_s"],
        **v1_info,
        "path_stats": training.path_stats,
        "loss_history": training.method_stats["loss_history"],
        "cache_stats": training.method_stats["cache_stats"],
        "cache_config": training.method_stats["caches"]["cache"]["config"],
        "nonfinite_v1_pixels": int(np.count_nonzero(~np.isfinite(v1_image).all(axis=-1))),
    }
    artifacts = _snapshot_artifacts(settings, weights, v1_image, v1_variance)
    fields = dict(
        key=key, scene_name=prepared.scene.name, scene_fingerprint=prepared.scene.fingerprint,
        method=method, params=params.model_dump(mode="json"), seed=seed,
        width=prepared.scene.resolution[0], height=prepared.scene.resolution[1],
        train_frames=train_frames, v1_spp=v1_spp, reference_id=prepared.reference.id,
        stats=stats, device=prepared.device, device_key=prepared.device["device_key"],
        created_at=started, **versions_of(method))
    if row is not None:  # replace the damaged one's row
        store.delete_snapshot(row.id)
    try:
        stored = store.add_snapshot(artifacts=artifacts, **fields)
    except DuplicateKeyError as err:  # made concurrently by another job: keep that one
        return _load(err.existing, settings)
    return Snapshot(key=key, id=stored.id, weights=weights, v1_image=v1_image,
                    v1_variance=v1_variance, stats=stats, created_now=True)


def render_v1(scene: Any, integrator: Any, spp: int,
              seed: int) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """The converged cache-at-v1 image and the per-pixel variance of that mean.

    ``integrator`` is an adaptive-termination integrator without a v1 mask.
    The image is rendered in ``n >= 2`` equal passes (``V1_PASSES``, fewer
    when ``spp`` is smaller; more when one pass would exceed
    ``V1_PASS_LANES``), each with its own seed, so the pass means are
    independent: the variance of the mean is their sample variance / n. When
    ``spp`` is not a multiple of n the last pass is not cut short (every pass
    has the same count): up to n - 1 more samples than asked are rendered.
    Returns (image, variance of the image, info: spp rendered, passes, seconds).
    """
    if spp < 2:
        raise ValueError(f"the v1 image needs at least 2 spp for its variance, got {spp}")
    width, height = scene.resolution
    max_per_pass = max(1, V1_PASS_LANES // (width * height))
    per_pass = min(max_per_pass, -(-spp // min(V1_PASSES, spp)))
    passes = max(2, -(-spp // per_pass))
    # Unlike a reference, a non-finite pixel is counted with the snapshot, not refused.
    moments = RunningMoments()
    seconds = render_passes(scene.scene, integrator, pass_spp=per_pass, passes=passes,
                            seed_of=lambda index: derive_seed(seed, index), sink=moments)
    v1 = moments.estimate()
    info = {"v1_spp_rendered": per_pass * passes, "v1_passes": passes, "v1_render_s": seconds}
    return v1.mean.astype(np.float32), v1.variance_of_mean.astype(np.float32), info


def _snapshot_artifacts(settings: Settings, weights: dict[str, np.ndarray],
                        v1_image: np.ndarray, v1_variance: np.ndarray) -> list[dict[str, Any]]:
    artifacts = ArtifactStore(settings.artifacts_dir)
    scratch = settings.data_dir / "tmp"
    scratch.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    np.savez(buffer, **weights)
    records = [
        artifact_record(artifacts, buffer.getvalue(), "cache_weights", ".npz",
                        "application/x-npz"),
        artifact_record(artifacts, encode_image(write_exr, v1_image, scratch / "v1.exr"),
                        "v1_image", ".exr", "image/x-exr"),
        artifact_record(artifacts, encode_image(write_exr, v1_variance, scratch / "v1var.exr"),
                        "v1_variance", ".exr", "image/x-exr"),
    ]
    for record in records:
        record.pop("seed")
    return records


def _load(row: Any, settings: Settings) -> Snapshot:
    artifacts = ArtifactStore(settings.artifacts_dir)
    paths = {a.kind: artifacts.path_of(a.path) for a in row.artifacts}
    with np.load(paths["cache_weights"]) as data:
        weights = {name: data[name] for name in data.files}
    # A snapshot stored before the v1 variance was kept has no "v1_variance": the
    # KeyError makes the caller render it again (its bias map needs the variance).
    return Snapshot(key=row.key, id=row.id, weights=weights,
                    v1_image=read_exr(paths["v1_image"]),
                    v1_variance=read_exr(paths["v1_variance"]), stats=row.stats,
                    created_now=False)
