"""The timing protocol: what a reported time means.

Dr.Jit records work lazily and launches kernels asynchronously, so a clock read
without synchronising measures only the tracing of Python code. Every timed
stage therefore evaluates its outputs and calls ``dr.sync_thread()`` before the
clock is read. The first call of a kernel JIT-compiles it (0.3-5 s; later
processes hit the kernel cache in ``~/.drjit``): frame loops run one warm-up
frame that is excluded from the timings and reported separately.
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
        self._nested: list[float] = []   # per open stage: seconds spent in its inner stages

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


def summarize(frames: list[dict[str, float]], warmup_s: float) -> dict[str, Any]:
    """Per-stage mean/median/min over frames, frame totals, and the warm-up time."""
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
        "per_frame": frames,
    }
