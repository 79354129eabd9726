"""Render jobs on animated scenes: per-frame references, per-frame errors, recovery
(docs/animation.md).

The executor hands a job whose scene is animated (renderers.scenes.animation) to
:func:`execute_animated`, which

1. renders (or loads) one reference per distinct frame state: a static segment
   shares one, continuous motion has one per frame. Each is keyed like any
   reference (jobs.protocol.references) with a fingerprint that joins the scene's
   with the frame state's key;
2. renders every seed's frames with the animation applied before each frame
   (FrameHooks.before_frame): the update's time is a stage of its own, 'scene
   update', outside the method's frame time;
3. scores every frame against its own reference (MRSE and HDR-FLIP), averages over
   seeds with an interval, measures the recovery after each change (metrics.recovery)
   and the flicker over the static region of consecutive frames
   (jobs.protocol.flicker);
4. stores the run as any other (jobs.protocol.executor.store_run): its image is the
   mean of the frames of the last segment (the frames showing the last frame's
   state), scored against that segment's reference; the per-frame errors, recovery
   times, flicker and scene-update times are the run's ``metrics['animation']``.
"""

from __future__ import annotations

import dataclasses
import gc
from collections import deque
from collections.abc import Callable
from itertools import pairwise
from typing import Any

import numpy as np

from jobs.protocol.flicker import frame_flicker, run_flicker, seed_flicker, static_mask
from jobs.protocol.job import RenderJob
from jobs.protocol.references import LoadedReference, get_or_render_reference
from jobs.record.config import Settings
from jobs.record.store import Store
from metrics.denoised import ACCUMULATED_FRAMES
from metrics.errors import mrse
from metrics.flip import flip_hdr
from metrics.recovery import RECOVERY_TOLERANCE, STEADY_FRAMES, frame_error_curve, recoveries
from metrics.statistics import RunningMoments
from renderers.methods.base import FrameHooks, RenderOutput
from renderers.scenes.animation import AnimationPlayer
from renderers.seeding import digest

Progress = Callable[[str, int, int], None]


def frame_scene(scene: Any, state_key: str) -> Any:
    """``scene`` (a LoadedScene) named as showing the frame state ``state_key``: its
    references are keyed by this fingerprint."""
    return dataclasses.replace(scene, fingerprint=digest("animation-frame", scene.fingerprint,
                                                         state_key))


def frame_references(store: Store, settings: Settings, scene: Any, player: AnimationPlayer,
                     reference_settings: Any, frames: int,
                     progress: Progress | None = None) -> list[LoadedReference]:
    """One reference per frame, rendered once per distinct state (module docstring)."""
    animation = player.animation
    keys = [animation.state_key(frame) for frame in range(frames)]
    distinct = list(dict.fromkeys(keys))
    by_key: dict[str, LoadedReference] = {}
    for number, key in enumerate(distinct):
        player.apply(keys.index(key))
        by_key[key] = get_or_render_reference(
            store, settings.references_dir, frame_scene(scene, key), reference_settings,
            progress=(lambda done, total, n=number: progress(
                f"reference {n + 1}/{len(distinct)}", done, total)) if progress else None)
    return [by_key[key] for key in keys]


@dataclasses.dataclass
class AnimatedSeed:
    """One seed's frames scored against their references."""

    output: RenderOutput
    frame_mrse: list[float]
    frame_flip: list[float]
    flicker: float | None          # jobs.protocol.flicker's seed flicker
    moments: RunningMoments        # of the last segment's frames
    last_frames: list[np.ndarray]


def static_masks(references: list[LoadedReference]) -> list[np.ndarray | None]:
    """Each frame's static region against the frame before it (None for frame 0)."""
    return [None, *(static_mask(previous, current)
                    for previous, current in pairwise(references))]


def render_animated_seed(render: Callable[[FrameHooks], RenderOutput], player: AnimationPlayer,
                         references: list[LoadedReference], eps: float, last_segment: int,
                         statics: list[np.ndarray | None], *, first_frame: int,
                         progress: Callable[[int, int], None] | None) -> AnimatedSeed:
    """Run one seed's frame loop with the animation applied before each frame, keeping
    each frame's error (MRSE, HDR-FLIP) against its reference, its flicker against the
    frame before it over ``statics`` (:func:`static_masks`) and the mean of the frames
    from ``last_segment`` on (the run's image)."""
    errors: list[float] = []
    flips: list[float] = []
    flickers: list[float | None] = []
    previous: list[np.ndarray] = []
    moments = RunningMoments()
    last: deque[np.ndarray] = deque(maxlen=ACCUMULATED_FRAMES)
    segment_mean: list[np.ndarray] = []

    def on_frame(index: int, frame: np.ndarray, _accumulated: np.ndarray) -> None:
        reference = references[index]
        errors.append(float(mrse(frame, reference.mean, eps)))
        flips.append(float(flip_hdr(reference.mean, frame, reference.flip_exposures)[0]))
        static = statics[index]
        if previous and static is not None:
            flickers.append(frame_flicker(previous[0], frame, reference.mean, static, eps))
        previous[:] = [frame]
        last.append(frame)
        if index >= last_segment:
            moments.add(frame)
            count = index - last_segment + 1
            segment_mean[:] = [frame.copy() if count == 1
                               else segment_mean[0] + (frame - segment_mean[0]) / count]

    player.apply(0)   # the warm-up renders frame 0's state
    gc.collect()
    output = render(FrameHooks(on_frame=on_frame, before_frame=player.apply, progress=progress,
                               first_frame=first_frame))
    output.accumulated = segment_mean[0]
    return AnimatedSeed(output, errors, flips, seed_flicker(flickers), moments, list(last))


def last_segment_start(player: AnimationPlayer, frames: int) -> int:
    """The first frame of the run's last segment: frames from it on show the last
    frame's state."""
    last = player.animation.state_key(frames - 1)
    start = frames - 1
    while start > 0 and player.animation.state_key(start - 1) == last:
        start -= 1
    return start


def update_stage(seconds: list[float]) -> dict[str, Any]:
    """The 'scene update' stage: every update of the run's frames (not its references)."""
    return {"updates": len(seconds), "total_s": float(np.sum(seconds)),
            "median_s": float(np.median(seconds)) if seconds else None}


def execute_animated(job: RenderJob, prepared: Any, store: Store, settings: Settings,
                     progress: Progress | None, idempotency_key: str | None,
                     extra: dict[str, Any]) -> Any:
    """Run ``job`` on its animated scene and store it (module docstring)."""
    from jobs.protocol.executor import SeedRender, store_run
    from renderers.methods import get_method

    spec, scene = job.spec, prepared.scene
    method = get_method(spec.method)
    player = scene.player
    references = frame_references(store, settings, scene, player,
                                  spec.reference.settings(job.max_depth), spec.frames, progress)
    segment = last_segment_start(player, spec.frames)
    param_json = job.params.model_dump(mode="json")
    statics = static_masks(references)
    player.update_seconds.clear()   # the references' updates are not the run's
    seeds: list[AnimatedSeed] = []
    for seed in range(spec.seed_start, spec.seed_start + spec.seeds):
        label = f"seed {seed + 1 - spec.seed_start}/{spec.seeds}"
        seeds.append(render_animated_seed(
            lambda hooks, seed=seed: method.render(
                scene, job.params,
                seed_parts=(scene.fingerprint, spec.method, param_json, spec.spp, seed),
                spp=spec.spp, frames=spec.frames, hooks=hooks),
            player, references, spec.eps, segment, statics,
            first_frame=(seed - spec.seed_start) * spec.frames,
            progress=(lambda done, total, label=label: progress(label, done, total))
            if progress else None))
    errors = np.array([s.frame_mrse for s in seeds])
    flips = np.array([s.frame_flip for s in seeds])
    animation = {
        "digest": scene.animation.digest(),
        "change_frames": scene.animation.change_frames(),
        "change_labels": scene.animation.change_labels(),
        "last_segment_start": segment,
        "frame_mrse": frame_error_curve(errors) if np.all(np.isfinite(errors)) else None,
        "recovery": (recoveries(errors, scene.animation.change_frames())
                     if np.all(np.isfinite(errors)) else None),
        "recovery_rule": {"tolerance": RECOVERY_TOLERANCE, "steady_frames": STEADY_FRAMES},
        "frame_flip": frame_error_curve(flips) if np.all(np.isfinite(flips)) else None,
        "flicker": run_flicker([s.flicker for s in seeds],
                               [float(m.mean()) for m in statics if m is not None]),
        "frame_references": [reference.id for reference in references],
        "scene_update": update_stage(player.update_seconds),
    }
    if animation["frame_mrse"] is None:
        animation["note"] = "a frame's error is NaN or infinite: no mean over seeds is taken"
    rendered = [SeedRender(s.output, {"frame_mrse": s.frame_mrse}, s.moments, s.last_frames)
                for s in seeds]
    return store_run(job, dataclasses.replace(prepared, reference=references[-1]), rendered,
                     store, settings, idempotency_key=idempotency_key,
                     extra={**extra, "animation": animation})
