"""The timing protocol: what a reported time means.

Dr.Jit records work lazily and launches kernels asynchronously, so a clock read
without synchronising measures only the tracing of Python code. Every timed
stage therefore evaluates its outputs and calls ``dr.sync_thread()`` before the
clock is read. The first call of a kernel JIT-compiles it (0.3-5 s; later
processes hit the kernel cache in ``~/.drjit``): frame loops run one warm-up
frame that is excluded from the timings and reported separately.

Every frame is timed twice: per stage, and as a whole (``StageTimer.frame``).
The frame time proper (``frame_median_s``) is the sum of the stages; the whole
frame also holds what runs between them (Python, building the records), which
the breakdown reports as 'other'.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from statistics import median
from typing import Any

import drjit as dr

PROTOCOL = (
    "steady-state seconds per frame: one warm-up frame (JIT compilation) excluded and "
    "reported separately as warmup_s; outputs evaluated and the device synchronised "
    "(dr.eval + dr.sync_thread) before every clock read; wall clock time.perf_counter"
)


def synchronize(*values: Any) -> None:
    """Evaluate pending Dr.Jit work for ``values`` and wait for the device."""
    if values:
        dr.eval(*values)
    dr.sync_thread()


class StageTimer:
    """Accumulates synchronised wall time per named stage within one frame.

    Stages may nest (the deferred cache ``inference`` runs inside
    ``mi.render``, timed as ``render``): a stage's time excludes the time of
    the stages nested in it, so the stages of a frame add up to its wall time.
    """

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.frame_s = 0.0
        self._nested: list[float] = []   # per open stage: seconds spent in its inner stages

    @contextmanager
    def frame(self) -> Iterator[None]:
        """Time a whole frame (its stages and everything between them) as ``frame_s``."""
        synchronize()
        start = time.perf_counter()
        yield
        synchronize()
        self.frame_s = time.perf_counter() - start

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time a block. The block must ``synchronize(outputs)`` its lazy results
        before it ends; the device is synchronised again before the clock is read."""
        synchronize()
        start = time.perf_counter()
        self._nested.append(0.0)
        try:
            yield
            synchronize()
        finally:
            elapsed = time.perf_counter() - start
            inner = self._nested.pop()
            if self._nested:
                self._nested[-1] += elapsed
        self.seconds[name] = self.seconds.get(name, 0.0) + elapsed - inner


#: The columns of the NIRC paper's Table 1 (Sec. 6.2) as stage names, in its order:
#: render paths, training paths, model training, model inference.
TABLE_1_STAGES = ("render", "training_paths", "training", "inference")


def breakdown(frames: list[dict[str, float]], whole_s: list[float]) -> dict[str, Any]:
    """Table-1-style time breakdown: the median seconds of every stage, and of 'other'.

    ``frames``: each frame's seconds per stage; ``whole_s``: each frame's whole
    time (:meth:`StageTimer.frame`). 'other' is a frame's whole time minus its
    stages. Stages come in Table 1's order, then any others by name. Without an
    ``inference`` stage the cache queries run inside ``render`` (one fused
    kernel) and ``inference_in_render`` says so. Medians do not add up: the
    parts sum to ``frame_s`` (the median whole frame) up to the frames' spread.
    """
    order = {name: index for index, name in enumerate(TABLE_1_STAGES)}
    names = sorted({name for frame in frames for name in frame},
                   key=lambda name: (order.get(name, len(order)), name))
    parts = {name: median(frame.get(name, 0.0) for frame in frames) for name in names}
    parts["other"] = median(max(whole - sum(frame.values()), 0.0)
                            for frame, whole in zip(frames, whole_s, strict=True))
    return {
        "statistic": "median over the timed frames, seconds",
        "parts_s": parts,
        "frame_s": median(whole_s),
        "inference_in_render": "inference" not in parts,
    }


def summarize(frames: list[dict[str, float]], warmup_s: float,
              whole_s: list[float]) -> dict[str, Any]:
    """Per-stage mean/median/min over frames, frame totals, the warm-up time and
    the breakdown (``whole_s``: each frame's whole time, see :func:`breakdown`)."""
    stages = sorted({name for frame in frames for name in frame})
    per_stage = {}
    for name in stages:
        values = [frame.get(name, 0.0) for frame in frames]
        per_stage[name] = {
            "mean_s": sum(values) / len(values),
            "median_s": median(values),
            "min_s": min(values),
        }
    totals = [sum(frame.values()) for frame in frames]
    frame_median = median(totals) if totals else 0.0
    return {
        "protocol": PROTOCOL,
        "frames": len(frames),
        "frame_mean_s": sum(totals) / len(totals) if totals else 0.0,
        "frame_median_s": frame_median,
        "stages": per_stage,
        "warmup_s": warmup_s,
        # The warm-up frame = compilation + one steady-state frame.
        "compile_s_estimate": max(warmup_s - frame_median, 0.0),
        "breakdown": breakdown(frames, whole_s),
        "per_frame": frames,
    }
