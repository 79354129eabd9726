"""Per-frame error of an animated run and recovery after a change (docs/animation.md).

``errors[s, f]`` is seed s's MRSE of frame f against frame f's own reference. The
seed-averaged error m(f) carries a Student-t interval over the K seeds. After a
change at frame k, whose segment runs to frame e (the next change or the last
frame), the method's steady error on the segment is the mean of m over the
segment's last ``steady_frames`` frames (the steady window, which starts at
w = e - steady_frames + 1), and the recovery time is the number of frames after k
until m stays within ``tolerance`` (10 % by default) of it:

    r = min { r >= 0 : m(k + j) <= (1 + tolerance) * steady for all r <= j < w - k }

(r = w - k where no earlier frame qualifies: recovered only inside the window). Its
interval is a percentile bootstrap over seeds: the seeds drawn with replacement,
m, the steady error and r computed again from the draw.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

#: Relative excess over the steady error within which a frame counts as recovered.
RECOVERY_TOLERANCE = 0.10
#: Frames at the end of a segment whose mean error is the steady error.
STEADY_FRAMES = 4
#: Bootstrap draws of the recovery interval, and its level.
BOOTSTRAP_DRAWS = 2000
CONFIDENCE = 0.95


def frame_error_curve(errors: np.ndarray, confidence: float = CONFIDENCE) -> dict[str, Any]:
    """Seed mean of each frame's error with a Student-t interval (None with one seed).
    ``errors``: (seeds, frames), finite (a non-finite error is refused, not averaged)."""
    errors = np.asarray(errors, dtype=np.float64)
    if not np.all(np.isfinite(errors)):
        raise ValueError("a frame's error is NaN or infinite: no mean over seeds is taken")
    seeds = errors.shape[0]
    mean = errors.mean(axis=0)
    if seeds < 2:
        return {"mean": mean.tolist(), "low": None, "high": None, "seeds": seeds}
    from scipy import stats  # imported here: a render process starts without it

    half = stats.t.ppf(0.5 + confidence / 2, seeds - 1) * errors.std(axis=0, ddof=1) \
        / np.sqrt(seeds)
    return {"mean": mean.tolist(), "low": (mean - half).tolist(),
            "high": (mean + half).tolist(), "seeds": seeds}


@dataclass(frozen=True)
class Recovery:
    """Recovery after the change at ``change_frame`` (module docstring)."""

    change_frame: int
    segment_end: int                  # last frame of the segment after the change
    steady_frames: int
    steady_error: float
    error_before: float | None        # m(k - 1): the error just before the change
    error_at_change: float            # m(k)
    frames: int                       # r
    low: float | None                 # bootstrap interval of r
    high: float | None
    within_window: bool               # recovered only inside the steady window
    tolerance: float

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def recovery_frames(curve: np.ndarray, change: int, window_start: int, steady: float,
                    tolerance: float) -> int:
    """r of the module docstring for one seed-averaged curve."""
    limit = (1 + tolerance) * steady
    recovered = window_start - change
    for offset in range(window_start - change - 1, -1, -1):
        if curve[change + offset] > limit:
            break
        recovered = offset
    return recovered


def recovery(errors: np.ndarray, change: int, segment_end: int, *,
             steady_frames: int = STEADY_FRAMES, tolerance: float = RECOVERY_TOLERANCE,
             draws: int = BOOTSTRAP_DRAWS, confidence: float = CONFIDENCE,
             seed: int = 0) -> Recovery | None:
    """Recovery after the change at frame ``change`` on the segment ending at
    ``segment_end`` (inclusive); None where the segment is shorter than the steady
    window and one frame before it."""
    errors = np.asarray(errors, dtype=np.float64)
    if not np.all(np.isfinite(errors)):
        raise ValueError("a frame's error is NaN or infinite: no recovery is measured")
    window_start = segment_end - steady_frames + 1
    if window_start <= change or not 0 < change <= segment_end < errors.shape[1]:
        return None

    def measure(sample: np.ndarray) -> int:
        curve = sample.mean(axis=0)
        steady = float(curve[window_start:segment_end + 1].mean())
        return recovery_frames(curve, change, window_start, steady, tolerance)

    curve = errors.mean(axis=0)
    steady = float(curve[window_start:segment_end + 1].mean())
    frames = measure(errors)
    low = high = None
    seeds = errors.shape[0]
    if seeds >= 2:
        rng = np.random.default_rng(seed)
        draws_r = [measure(errors[rng.integers(0, seeds, seeds)]) for _ in range(draws)]
        tail = (1 - confidence) / 2
        low, high = (float(q) for q in np.quantile(draws_r, [tail, 1 - tail]))
    return Recovery(change_frame=change, segment_end=segment_end, steady_frames=steady_frames,
                    steady_error=steady, error_before=float(curve[change - 1]),
                    error_at_change=float(curve[change]), frames=frames, low=low, high=high,
                    within_window=frames == window_start - change, tolerance=tolerance)


def recoveries(errors: np.ndarray, changes: list[int], **options: Any) -> list[dict[str, Any]]:
    """Recovery after every change inside the run's frames (its segment ends before the
    next change), as JSON; a segment too short to measure is listed with a reason."""
    frames = np.asarray(errors).shape[1]
    inside = [change for change in changes if 0 < change < frames]
    ends = [*(change - 1 for change in inside[1:]), frames - 1] if inside else []
    found = []
    for change, end in zip(inside, ends, strict=True):
        measured = recovery(errors, change, end, **options)
        found.append(measured.to_json() if measured is not None else {
            "change_frame": change, "segment_end": end,
            "note": "segment too short for the steady window"})
    return found
