"""What every render method has in common: parameters, the frame loop, its output.

A method is a pure function of (scene, method parameters, seed, spp, frames)
-> images + statistics (DESIGN.md, "Layout"). The frame loop gives all methods
the same real-time semantics and the same timing protocol: one warm-up frame
(excluded, reported), then F timed frames, each rendered with its own derived
seed and accumulated into the running mean.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict

from renderers.seeding import derive_seed
from renderers.timing import StageTimer, summarize


class MethodParams(BaseModel):
    """Base of every method's parameter model: unknown fields are errors."""

    model_config = ConfigDict(extra="forbid", frozen=True)


@dataclass
class RenderOutput:
    """What a method returns for one seed."""

    accumulated: np.ndarray                 # (H, W, 3) float32 mean of all frames
    frames: list[np.ndarray] | None         # per-frame images when requested
    timings: dict[str, Any]                 # see renderers.timing.summarize
    path_stats: dict[str, Any] = field(default_factory=dict)


#: Renders frame ``index`` with ``seed``, timing its stages with ``timer``;
#: returns the frame's film tensor (RGB first, then the method's AOVs).
FrameFn = Callable[[int, int, StageTimer], Any]


def run_frames(
    render_frame: FrameFn,
    *,
    seed_parts: tuple[Any, ...],
    frames: int,
    keep_frames: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> RenderOutput:
    """The shared frame loop: warm-up, F timed frames, running mean, path statistics.

    ``seed_parts`` identify the render (scene fingerprint, method, params, seed
    index); frame f renders with ``derive_seed(*seed_parts, f)`` and the warm-up
    frame with a seed of its own, so it never correlates with a timed frame.
    """
    warmup = StageTimer()
    render_frame(-1, derive_seed(*seed_parts, "warmup"), warmup)
    warmup_s = sum(warmup.seconds.values())

    accumulated: np.ndarray | None = None
    depth_sum = 0.0
    kept: list[np.ndarray] = []
    frame_timings: list[dict[str, float]] = []
    for index in range(frames):
        timer = StageTimer()
        film = np.asarray(render_frame(index, derive_seed(*seed_parts, index), timer))
        frame_timings.append(timer.seconds)
        rgb = film[..., :3].astype(np.float32)
        # Running mean keeps memory constant however many frames run.
        accumulated = rgb.copy() if accumulated is None else accumulated + (rgb - accumulated) / (index + 1)
        if film.shape[-1] > 3:
            depth_sum += float(np.nanmean(film[..., 3]))
        if keep_frames:
            kept.append(rgb)
        if progress:
            progress(index + 1, frames)

    assert accumulated is not None
    return RenderOutput(
        accumulated=accumulated,
        frames=kept if keep_frames else None,
        timings=summarize(frame_timings, warmup_s),
        path_stats={"avg_path_vertices": depth_sum / frames},
    )
