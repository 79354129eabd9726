"""`nirc`: Neural Incident Radiance Cache, biased (Eq. 13) or unbiased (Eq. 10-12).

Real-time semantics (DESIGN.md): every frame first traces training paths
(a few % of the pixel count, at least ``min_train_paths``) and takes the
cache's training steps on their records, then renders the frame with the
updated cache — so frame f uses a cache trained on frames 0..f. Static scenes
may pre-train for ``pretrain_frames`` frames before the first timed frame.
Stages timed per frame: ``training_paths``, ``training``, ``render`` (path
tracing and cache inference run in one fused kernel and are timed together).
"""

from __future__ import annotations

import math
import time
from typing import Any, Literal

from pydantic import Field, model_validator

from renderers.methods.base import RenderOutput, run_frames
from renderers.methods.pt import PTParams
from renderers.seeding import derive_seed
from renderers.timing import StageTimer

NIRC_AOVS = ("depth", "cache_depth", "cache_vertices")


class NIRCParams(PTParams):
    """Parameters of the `nirc` method (PT core parameters included)."""

    estimator: Literal["biased", "unbiased"] = "biased"
    termination: Literal["bth", "sph"] = "bth"
    nc: list[int] | None = Field(None, description="N_c: [4] biased; per vertex, e.g. [3,1,1], unbiased")
    sph_c: float = Field(0.01, gt=0.0, le=1e6)
    train_fraction: float = Field(0.03, gt=0.0, le=1.0, description="training paths / pixels")
    min_train_paths: int = Field(4096, ge=1, le=1 << 22)
    record_depth: int = Field(3, ge=1, le=16, description="vertices per training path recorded")
    train_max_depth: int = Field(-1, ge=-1, le=1024, description="-1: unbounded with roulette")
    pretrain_frames: int = Field(0, ge=0, le=100_000)
    cache: dict[str, Any] = Field(default_factory=dict, description="overrides of nirc_config()")

    @model_validator(mode="after")
    def _check_nc(self) -> NIRCParams:
        nc = self.sample_counts()
        if any(n < 1 or n > 256 for n in nc):
            raise ValueError("nc entries must be in 1..256")
        if self.estimator == "biased" and len(nc) != 1:
            raise ValueError("the biased estimator takes one N_c (e.g. nc=[4])")
        if self.estimator == "unbiased" and len(nc) > 3:
            raise ValueError("the unbiased estimator takes at most 3 entries (one per vertex)")
        if self.train_max_depth == 0:
            raise ValueError("train_max_depth must be -1 (unbounded) or >= 1")
        return self

    def sample_counts(self) -> list[int]:
        if self.nc is not None:
            return list(self.nc)
        return [4] if self.estimator == "biased" else [3, 1, 1]


def _plugins() -> tuple[str, str]:
    from renderers.integrators import nirc, path, training

    path.register(nirc.NIRC_PLUGIN, nirc.NIRCIntegrator)
    path.register("nirc_training", training.TrainingPathIntegrator)
    return nirc.NIRC_PLUGIN, "nirc_training"


def make_cache(scene: Any, params: NIRCParams, seed: int) -> Any:
    from renderers.caches import NeuralCache, nirc_config

    bbox = scene.scene.bbox()
    return NeuralCache(nirc_config(**params.cache), list(bbox.min), list(bbox.max), seed=seed)


def render(
    scene: Any, params: NIRCParams, *, seed_parts: tuple[Any, ...], spp: int, frames: int,
    keep_frames: bool = False, progress=None,
) -> RenderOutput:
    """Render ``frames`` frames with online training (see the module docstring)."""
    import mitsuba as mi

    from renderers.caches import TrainingRecords

    render_plugin, training_plugin = _plugins()
    core = {"max_depth": params.max_depth, "rr_depth": params.rr_depth,
            "rr_mode": params.rr_mode, "rr_survival": params.rr_survival}
    integrator = mi.load_dict({
        "type": render_plugin, **core, "estimator": params.estimator,
        "termination": params.termination, "sph_c": params.sph_c,
        "nc": ",".join(str(n) for n in params.sample_counts())})
    trainer = mi.load_dict({
        "type": training_plugin, **{**core, "max_depth": params.train_max_depth},
        "record_depth": params.record_depth})
    cache = make_cache(scene, params, derive_seed(*seed_parts, "cache"))
    integrator.cache = cache
    width, height = scene.resolution
    n_train = max(params.min_train_paths, math.ceil(params.train_fraction * width * height))

    def train(seed: int, timer: StageTimer) -> None:
        with timer.stage("training_paths"):
            records = trainer.trace_records(scene.scene, n_train, seed)
        with timer.stage("training"):
            cache.train(TrainingRecords(**records))

    pretrain_start = time.perf_counter()
    for index in range(params.pretrain_frames):
        train(derive_seed(*seed_parts, "pretrain", index), StageTimer())
    pretrain_s = time.perf_counter() - pretrain_start

    def render_frame(_index: int, seed: int, timer: StageTimer):
        train(derive_seed(seed, "train"), timer)
        with timer.stage("render", lambda: (image,)):
            image = mi.render(scene.scene, integrator=integrator, spp=spp, seed=seed)
        return image

    output = run_frames(render_frame, seed_parts=seed_parts, frames=frames, spp=spp,
                        aov_names=NIRC_AOVS, keep_frames=keep_frames, progress=progress)
    output.method_stats = {
        "train_paths_per_frame": n_train,
        "pretrain_frames": params.pretrain_frames,
        "pretrain_s": pretrain_s,
        "loss_history": list(cache.loss_history),
        "cache_stats": dict(cache.stats),
        "cache_config": cache.config.model_dump(mode="json"),
    }
    return output
