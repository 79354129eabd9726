"""Stored ``metrics['animation']`` of synthetic animated runs: per-frame errors drawn per
seed (a jump at each change that decays back to a steady level), scored by the same
functions as a rendered run (metrics.recovery), without rendering."""

from __future__ import annotations

from typing import Any

import numpy as np

from metrics.recovery import RECOVERY_TOLERANCE, STEADY_FRAMES, frame_error_curve, recoveries
from renderers.scenes.animated import get_animated


def frame_errors(changes: list[int], frames: int, seeds: int, *, steady: float, jump: float,
                 decay_frames: float, noise: float, seed: int) -> np.ndarray:
    """(seeds, frames) errors: ``steady`` times (1 + ``jump`` e^(-t / decay_frames)) t
    frames after the latest change, times log-normal noise of sigma ``noise``."""
    since = np.array([frame - max([0, *(c for c in changes if c <= frame)])
                      for frame in range(frames)], dtype=float)
    excess = np.where(since < np.arange(frames), jump * np.exp(-since / decay_frames), 0.0)
    rng = np.random.default_rng(seed)
    return steady * (1 + excess) * np.exp(noise * rng.standard_normal((seeds, frames)))


def animation_metrics(scene: str, frames: int, seeds: int = 4, **shape: Any) -> dict[str, Any]:
    """A run's ``metrics['animation']`` on the built-in animated ``scene``."""
    animation = get_animated(scene).animation
    changes = animation.change_frames()
    errors = frame_errors(changes, frames, seeds, **shape)
    return {"digest": animation.digest(), "change_frames": changes,
            "change_labels": animation.change_labels(),
            "last_segment_start": max([0, *(c for c in changes if c < frames)]),
            "frame_mrse": frame_error_curve(errors),
            "recovery": recoveries(errors, changes, draws=200),
            "recovery_rule": {"tolerance": RECOVERY_TOLERANCE, "steady_frames": STEADY_FRAMES},
            "frame_references": [], "scene_update": {"updates": frames, "total_s": 0.01,
                                                     "median_s": 0.0005}}
