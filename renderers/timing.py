"""The timing protocol: what a reported time means.

Dr.Jit records work lazily and launches kernels asynchronously, so a clock read
without synchronising measures only the tracing of Python code. Every timed
stage therefore evaluates its outputs and calls ``dr.sync_thread()`` before the
clock is read. The first call of a kernel JIT-compiles it (0.3-5 s; later
processes hit the kernel cache in ``~/.drjit``): frame loops run one warm-up
frame that is excluded from the timings and reported separately.

Two clocks per stage (docs/timing.md):

- **wall time**, ``time.perf_counter`` between two synchronisations: what the
  stage costs end to end on this machine;
- **kernel time**, the summed ``execution_time`` of the kernels Dr.Jit launched
  inside the stage (its kernel history, ``JitFlag.KernelHistory``; measured on
  the device on CUDA, with the host's monotonic clock around each kernel on
  LLVM). Wall minus kernel time is the **harness** share of the stage: Python
  tracing, code generation, host work, launch gaps. It is taken of one frame, a
  kernel frame (below), whose kernels ran inside its own clock's windows, so it is
  never negative; wall and kernel medians of different frames would not be
  comparable where frames differ (a frame that records a frozen pass anew, a cache
  whose work changes from frame to frame).

Recording the history is not free (a frozen replay copies every kernel's source
into it: ~10 % of a small frame, and the frame after pays for the caches it evicted),
so the two clocks are read in different frames (:func:`frame_kind`): **wall
frames** (history off: their wall time is the frame time) and, interleaved with them,
**kernel frames** (history on: their kernel time per stage); the frame after a kernel
frame is used by neither. Every frame renders and is accumulated alike.

Every frame is timed as a whole too (``StageTimer.frame``): what runs between
the stages (Python, building the records) is its part 'other'. Reading the
kernel history costs ~9 us per launch; it happens outside every stage's clock
and its time is subtracted from the whole frame and stored apart (``readout_s``). The frame time
(``frame_median_s``) is the sum of the stages of the median wall frame; the time
breakdown is that frame's parts (its stages and 'other'), so they add up to
its whole wall time, beside the kernel and harness parts of the median kernel frame
(its harness includes recording the history: an upper bound of a wall frame's). Medians
are lower medians (a frame that was measured).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from statistics import median_low
from typing import Any

import drjit as dr

PROTOCOL = (
    "steady-state seconds per frame: one warm-up frame (JIT compilation) excluded and "
    "reported separately as warmup_s; outputs evaluated and the device synchronised "
    "(dr.eval + dr.sync_thread) before every clock read; wall clock time.perf_counter; "
    "kernel time from Dr.Jit's kernel history, recorded only in kernel frames (every "
    "4th timed frame from the 2nd) and wall time from the wall frames (history off, "
    "not right after a kernel frame: half of the frames); the warm-up settles both "
    "states; harness = a kernel frame's wall time - its own kernel time (never another "
    "frame's: it includes recording the history); reading the history is "
    "timed apart and excluded; the frame time and its breakdown are those of the median "
    "wall frame (lower median), the kernel parts those of the median kernel frame"
)

#: The part of a frame outside its stages (StageTimer.frame minus the stages).
OTHER = "other"


def synchronize(*values: Any) -> None:
    """Evaluate pending Dr.Jit work for ``values`` and wait for the device."""
    if values:
        dr.eval(*values)
    dr.sync_thread()


def kernel_history_enabled() -> bool:
    """Whether Dr.Jit records the kernels it launches (``JitFlag.KernelHistory``)."""
    return bool(dr.flag(dr.JitFlag.KernelHistory))


@contextmanager
def kernel_history(on: bool = True) -> Iterator[None]:
    """Record Dr.Jit's kernel launches in this block (``on``; for :class:`StageTimer`) or
    not, then drop what no timer read, so the history (which holds each kernel's code)
    never grows outside a timed block. Dr.Jit keys a frozen function's recordings on
    every JIT flag, this one included: a frozen function called in both states records
    in both (the frame loop's warm-up settles both)."""
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, on):
        try:
            yield
        finally:
            dr.kernel_history_clear()


#: The kinds of timed frame: timed with the kernel history off (its wall time counts),
#: with it on (its kernel time counts), and the frame after a kernel frame (history off;
#: no statistic uses it: the history's copies evicted the caches it would have found
#: warm, measured +0.06 ms, +17 %, on an 8x8 `pt` frame, docs/timing.md).
WALL, KERNEL, AFTER_KERNEL = "wall", "kernel", "after-kernel"
#: Every how many timed frames one is a kernel frame, by default: W K A W W K A W ...
#: (A: after-kernel), half of the frames wall frames, a quarter kernel frames.
KERNEL_EVERY = 4


def frame_kind(index: int, every: int = KERNEL_EVERY) -> str:
    """The kind of timed frame ``index`` when every ``every``-th frame from the second
    (1, 1 + every, ...) is a kernel frame: the frame after one is an after-kernel frame
    unless it is a kernel frame too, the others are wall frames. 1: every frame a kernel
    frame (the old protocol, whose frame time includes recording the history); 0: none;
    both only to measure what recording it costs. Frame 0 is a wall frame unless every
    frame is a kernel frame, and two frames have one of each."""
    def kernel(at: int) -> bool:
        return every > 0 and at % every == 1 % every

    if kernel(index):
        return KERNEL
    return AFTER_KERNEL if index > 0 and kernel(index - 1) else WALL


def history_states(every: int = KERNEL_EVERY) -> tuple[bool, ...]:
    """The kernel-history flags the timed frames run under, on first: the warm-up runs
    its calls under them in turn (the first, which compiles, with the history on where
    any frame has it, for the compile time)."""
    return (True,) if every == 1 else (False,) if every == 0 else (True, False)


@dataclass
class KernelTally:
    """Kernels drained from the history: summed execution time, launches, and the
    host time Dr.Jit spent generating (``codegen``) and compiling (``backend``) them."""

    seconds: float = 0.0
    launches: int = 0
    codegen_s: float = 0.0
    compile_s: float = 0.0

    def add(self, other: KernelTally) -> None:
        self.seconds += other.seconds
        self.launches += other.launches
        self.codegen_s += other.codegen_s
        self.compile_s += other.compile_s


def drain_kernels() -> KernelTally:
    """Sum and clear the kernel history (empty when it is off). Times are in ms there."""
    tally = KernelTally()
    for kernel in dr.kernel_history():
        tally.seconds += 1e-3 * float(kernel.get("execution_time", 0.0))
        tally.launches += 1
        tally.codegen_s += 1e-3 * float(kernel.get("codegen_time", 0.0))
        tally.compile_s += 1e-3 * float(kernel.get("backend_time", 0.0))
    return tally


class StageTimer:
    """Wall and kernel time per named stage within one frame.

    Stages may nest (a caching integrator's ``inference`` where it runs inside
    ``mi.render``, timed as ``render``): a stage's time excludes the time of the stages nested
    in it, so the stages of a frame add up to its wall time, and so do their
    kernel times. Kernel time is known only while Dr.Jit's kernel history is on
    (:func:`kernel_history`); otherwise ``kernels`` is None.
    """

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.frame_s = 0.0
        self.kernels: dict[str, KernelTally] | None = {} if kernel_history_enabled() else None
        self.readout_s = 0.0              # reading the kernel history inside the frame
        self._open: list[str] = []        # the open stages, innermost last
        self._nested: list[float] = []    # per open stage: seconds spent in its inner stages

    def _drain_into(self, name: str) -> None:
        """Charge the kernels launched since the last drain to stage ``name``. Reading
        the history costs ~9 us per launch (measured): it happens outside every stage's
        clock and is kept apart (``readout_s``), not in the frame."""
        if self.kernels is not None:
            start = time.perf_counter()
            self.kernels.setdefault(name, KernelTally()).add(drain_kernels())
            spent = time.perf_counter() - start
            self.readout_s += spent
            if self._nested:    # inside an open stage's window: not that stage's time
                self._nested[-1] += spent

    @contextmanager
    def frame(self) -> Iterator[None]:
        """Time a whole frame (its stages and everything between them, less the reading of
        the kernel history) as ``frame_s``; kernels launched between the stages are the
        frame's 'other'."""
        synchronize()
        if self.kernels is not None:
            drain_kernels()   # launched before this frame
        start = time.perf_counter()
        yield
        synchronize()
        self.frame_s = time.perf_counter() - start - self.readout_s
        self._drain_into(OTHER)

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time a block. The block must ``synchronize(outputs)`` its lazy results
        before it ends; the device is synchronised again before the clock is read."""
        synchronize()
        self._drain_into(self._open[-1] if self._open else OTHER)
        start = time.perf_counter()
        self._open.append(name)
        self._nested.append(0.0)
        try:
            yield
            synchronize()
        finally:
            elapsed = time.perf_counter() - start
            self._open.pop()
            inner = self._nested.pop()
            if self._nested:
                self._nested[-1] += elapsed
            self._drain_into(name)
        self.seconds[name] = self.seconds.get(name, 0.0) + elapsed - inner

    def record(self, kind: str = "") -> FrameTime:
        """This frame's times (after :meth:`frame`), of ``kind`` (by default 'kernel' or
        'wall', as the history was on or off)."""
        kernels = self.kernels
        return FrameTime(
            stages=dict(self.seconds), whole_s=self.frame_s,
            kernel_s=None if kernels is None else {n: k.seconds for n, k in kernels.items()},
            launches=None if kernels is None else {n: k.launches for n, k in kernels.items()},
            readout_s=self.readout_s, kind=kind)


@dataclass
class FrameTime:
    """One timed frame: wall seconds per stage, the whole frame's wall seconds, and
    (with the kernel history on) kernel seconds and launches per stage and 'other'."""

    stages: dict[str, float]
    whole_s: float
    kernel_s: dict[str, float] | None = None
    launches: dict[str, int] | None = None
    readout_s: float = 0.0       # reading the kernel history: measurement, not the frame
    #: WALL, KERNEL or AFTER_KERNEL; by default as the kernel history was off or on
    #: (runs stored before the kinds had the history on in every frame).
    kind: str = ""

    def __post_init__(self) -> None:
        if not self.kind:
            self.kind = WALL if self.kernel_s is None else KERNEL

    @property
    def total_s(self) -> float:
        """The frame time proper: the sum of its stages."""
        return sum(self.stages.values())

    def parts(self) -> dict[str, float]:
        """Wall seconds per stage and 'other' (the whole frame less its stages)."""
        return {**self.stages, OTHER: max(self.whole_s - self.total_s, 0.0)}

    def kernel_parts(self) -> dict[str, float] | None:
        """Kernel seconds per stage and 'other' (None without the kernel history)."""
        if self.kernel_s is None:
            return None
        return {name: self.kernel_s.get(name, 0.0) for name in self.parts()}

    @property
    def kernel_total_s(self) -> float | None:
        return None if self.kernel_s is None else sum(self.kernel_s.values())

    def harness_parts(self) -> dict[str, float] | None:
        """Harness seconds per stage and 'other': this frame's wall time less its own
        kernel time, part by part (None without the kernel history). Both clocks are of
        this one frame and its kernels ran inside its stages' windows, so no part is
        negative (whatever other frames cost)."""
        kernel = self.kernel_parts()
        if kernel is None:
            return None
        return {name: seconds - kernel[name] for name, seconds in self.parts().items()}

    @property
    def harness_s(self) -> float | None:
        """This frame's whole wall time less its kernel time (None without the history)."""
        kernel = self.kernel_total_s
        return None if kernel is None else self.whole_s - kernel

    @property
    def harness_share(self) -> float | None:
        """:attr:`harness_s` over this frame's whole wall time."""
        harness = self.harness_s
        if harness is None:
            return None
        return harness / self.whole_s if self.whole_s > 0 else 0.0

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "stages": self.stages, "whole_s": self.whole_s,
                "kernel_s": self.kernel_s, "launches": self.launches,
                "readout_s": self.readout_s}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> FrameTime:
        return cls(stages=data["stages"], whole_s=data["whole_s"],
                   kernel_s=data.get("kernel_s"), launches=data.get("launches"),
                   readout_s=data.get("readout_s", 0.0), kind=data.get("kind", ""))


#: The columns of the NIRC paper's Table 1 (Sec. 6.2) as stage names, in its order:
#: render paths, training paths, model training, model inference.
TABLE_1_STAGES = ("render", "training_paths", "training", "inference")


def _ordered(names: set[str]) -> list[str]:
    """Stage names in Table 1's order, then any others by name, 'other' last."""
    order = {name: index for index, name in enumerate(TABLE_1_STAGES)}
    order[OTHER] = len(order) + 1
    return sorted(names, key=lambda name: (order.get(name, len(TABLE_1_STAGES)), name))


def wall_frames(frames: Sequence[FrameTime]) -> list[FrameTime]:
    """The frames whose wall time counts: the wall frames (kernel history off), or, where
    there are none, the kernel frames (runs stored before the frames were interleaved,
    or a measurement of what recording the history costs: the history in every frame),
    else all of them (a seed of a run whose one frame came after a kernel frame: the
    run's pooled timings take their wall times from its other seeds)."""
    return [f for f in frames if f.kind == WALL] or kernel_frames(frames) or list(frames)


def kernel_frames(frames: Sequence[FrameTime]) -> list[FrameTime]:
    """The frames whose kernel time counts: the kernel frames (kernel history on)."""
    return [f for f in frames if f.kind == KERNEL]


def median_frame(frames: Sequence[FrameTime],
                 key: Callable[[FrameTime], float] = lambda f: f.total_s) -> FrameTime:
    """The frame whose ``key`` (by default its stage total) is the (lower) median of the
    frames'."""
    return sorted(frames, key=key)[(len(frames) - 1) // 2]


def _kernel_total(frame: FrameTime) -> float:
    return frame.kernel_total_s or 0.0


def breakdown(frames: Sequence[FrameTime]) -> dict[str, Any]:
    """Table-1-style split of the median wall frame (:func:`median_frame` of
    :func:`wall_frames`): wall seconds of every stage and of 'other', adding up to
    ``frame_s``, that frame's whole wall time (its stages to the reported frame time);
    and, where there are kernel frames, the kernel seconds of the median kernel frame
    (by its kernel total; without wall frames, of the median frame itself) with that
    frame's harness, its own wall - kernel part by part (:meth:`FrameTime.harness_parts`),
    its whole wall time (``kernel_frame_s``) and harness share. Without an
    ``inference`` stage the cache queries run inside ``render`` (one fused kernel) and
    ``inference_in_render`` says so."""
    frame = median_frame(wall_frames(frames))
    parts = frame.parts()
    kernels = kernel_frames(frames)
    if frame.kind == KERNEL:   # no wall frames: both clocks of the one frame
        kernels = [frame]
    measured = median_frame(kernels, _kernel_total) if kernels else None
    kernel = None if measured is None else measured.kernel_parts()
    names = _ordered(set(parts) | set(kernel or {}))
    result: dict[str, Any] = {
        "statistic": "the median wall frame (lower median of the stage totals), seconds; "
                     "kernel parts: the median kernel frame (lower median of the kernel "
                     "totals)",
        "parts_s": {name: parts.get(name, 0.0) for name in names},
        "frame_s": frame.whole_s,
        "inference_in_render": "inference" not in parts,
    }
    if measured is not None and kernel is not None:
        harness = measured.harness_parts() or {}
        result["kernel_parts_s"] = {name: kernel.get(name, 0.0) for name in names}
        result["harness_parts_s"] = {name: harness.get(name, 0.0) for name in names}
        result["frame_kernel_s"] = sum(kernel.values())
        result["kernel_frame_s"] = measured.whole_s
        result["harness_share"] = measured.harness_share
    return result


def _stage_summary(walls: Sequence[FrameTime], kernels: Sequence[FrameTime],
                   name: str) -> dict[str, float]:
    """Statistics of one stage: of its wall time over the wall frames and, where there
    are kernel frames, of its kernel time, harness (each kernel frame's own wall - kernel
    time of the stage) and launches over them."""
    wall = [f.parts().get(name, 0.0) for f in walls]
    summary: dict[str, float] = {"mean_s": sum(wall) / len(wall), "median_s": median_low(wall),
                                 "min_s": min(wall)}
    if kernels:
        kernel = median_low([(f.kernel_parts() or {}).get(name, 0.0) for f in kernels])
        summary["kernel_median_s"] = kernel
        summary["harness_median_s"] = median_low([(f.harness_parts() or {}).get(name, 0.0)
                                                  for f in kernels])
        summary["launches_median"] = median_low([(f.launches or {}).get(name, 0)
                                                 for f in kernels])
    return summary


def device_time(frames: Sequence[FrameTime]) -> dict[str, Any] | None:
    """Whole-frame wall time over the wall frames and kernel time over the kernel frames
    (None without kernel frames): their medians, the harness of the kernel frames (each
    one's wall - kernel time: :attr:`FrameTime.harness_s`) and its share of that frame,
    medians over them, and the kernel launches per frame."""
    kernels = kernel_frames(frames)
    if not kernels:
        return None
    wall = median_low([f.whole_s for f in wall_frames(frames)])
    kernel = median_low([_kernel_total(f) for f in kernels])
    return {
        "wall_median_s": wall,
        "kernel_median_s": kernel,
        "harness_median_s": median_low([f.harness_s or 0.0 for f in kernels]),
        "harness_share": median_low([f.harness_share or 0.0 for f in kernels]),
        "launches_median": median_low([sum((f.launches or {}).values()) for f in kernels]),
        # Reading the kernel history, kept out of every figure above.
        "readout_median_s": median_low([f.readout_s for f in kernels]),
    }


@dataclass
class Warmup:
    """The untimed warm-up: its wall seconds, its frames and, from the kernel history of
    its calls with it on, the seconds Dr.Jit spent compiling kernels (``compile_s``,
    None without such calls)."""

    seconds: float = 0.0
    compile_s: float | None = None
    frames: int = 1


def summarize(frames: Sequence[FrameTime], warmup: Warmup,
              load: dict[str, Any] | None = None) -> dict[str, Any]:
    """What a render stores of its time: per-stage statistics, the frame time (stage total
    of the median wall frame), the breakdown, whole-frame device time, the warm-up and
    compilation, the machine load during the frames, how many frames of each kind
    (``frame_kinds``), and every frame (``frames_detail``, each with its kind;
    ``per_frame`` keeps each frame's stage seconds). Wall-time statistics are over the
    wall frames, kernel-time statistics over the kernel frames."""
    if not frames:
        raise ValueError("no timed frame to summarize")
    walls, kernels = wall_frames(frames), kernel_frames(frames)
    names = _ordered({name for f in frames for name in f.parts()})
    frame_time = median_frame(walls).total_s
    totals = [f.total_s for f in walls]
    return {
        "protocol": PROTOCOL,
        "frames": len(frames),
        "frame_kinds": {kind: sum(f.kind == kind for f in frames)
                        for kind in (WALL, KERNEL, AFTER_KERNEL)},
        "frame_mean_s": sum(totals) / len(totals),
        "frame_median_s": frame_time,
        "stages": {name: _stage_summary(walls, kernels, name)
                   for name in names if name != OTHER},
        "device_time": device_time(frames),
        "warmup_s": warmup.seconds,
        "warmup_frames": warmup.frames,
        "compile_s": warmup.compile_s,
        # The warm-up frames = compilation + as many steady-state frames.
        "compile_s_estimate": max(warmup.seconds - warmup.frames * frame_time, 0.0),
        "breakdown": breakdown(frames),
        "load": load,
        "per_frame": [f.stages for f in frames],
        "frames_detail": [f.to_json() for f in frames],
    }


def pooled(seed_timings: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """One summary over the timed frames of several seeds (each a :func:`summarize`
    result), so that a run's frame time, stages and breakdown come from one statistic
    over the same frames. Warm-up, compilation and the frozen functions' recordings
    are the first seed's (every seed's recordings in ``frozen_seeds``); the load is
    flagged when any seed's was."""
    frames = [FrameTime.from_json(f) for t in seed_timings for f in t["frames_detail"]]
    first = seed_timings[0]
    summary = summarize(frames, Warmup(first["warmup_s"], first.get("compile_s")),
                        merge_loads([t.get("load") for t in seed_timings]))
    del summary["frames_detail"], summary["per_frame"]   # kept per seed
    summary["frozen"] = first.get("frozen")
    summary["frozen_seeds"] = [t.get("frozen") for t in seed_timings]
    return summary


def merge_loads(loads: Sequence[dict[str, Any] | None]) -> dict[str, Any] | None:
    """The load of several timed windows: loaded when any was, unknown (None) when none
    was but one is unknown, with their reasons."""
    known = [load for load in loads if load]
    if not known:
        return None
    verdicts = [load["loaded"] for load in known]
    return {"loaded": True if any(verdicts) else None if None in verdicts else False,
            "reasons": list(dict.fromkeys(r for load in known for r in load["reasons"])),
            "windows": known}
