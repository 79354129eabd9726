"""Whether other work competed for the CPU while a timing was taken.

A timing from a shared machine is only as good as the machine was quiet. The load
average cannot tell: the measured process alone keeps it near the core count.
What can:

- the kernel's CPU pressure (``/proc/pressure/cpu``, Linux PSI): the share of the
  window during which some runnable task waited for a CPU. Measured on the 2-core
  machine (docs/timing.md): 0.00-0.03 with a render alone, 0.5 with one CPU-bound
  process beside it, 0.96-0.99 with two;
- the process's own CPU time against the wall time (``time.process_time``): on the
  LLVM backend Dr.Jit's worker threads keep every core busy (1.95 of 2 cores with a
  render alone, 1.0-1.3 with one or two CPU-bound processes beside it);
- involuntary context switches of the process (``getrusage``; ~35/s alone,
  200-250/s beside CPU-bound processes), reported, not judged.

A window is flagged ``loaded`` when the stall share exceeds :data:`STALL_LIMIT`;
without pressure information, on the LLVM backend, when the process used less than
:data:`CPU_SHARE_LIMIT` of the cores; otherwise its load is unknown (None).
"""

from __future__ import annotations

import os
import resource
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: A window is loaded when some task waited for a CPU during more than this share of it.
STALL_LIMIT = 0.10
#: Without pressure information (LLVM backend): loaded below this share of the cores.
CPU_SHARE_LIMIT = 0.75
PRESSURE_FILE = Path("/proc/pressure/cpu")


def cpu_stall_us() -> int | None:
    """Total microseconds some task waited for a CPU since boot (None where the kernel
    does not report CPU pressure)."""
    try:
        first = PRESSURE_FILE.read_text(encoding="ascii").splitlines()[0]
        return int(first.rsplit("total=", 1)[1])
    except (OSError, IndexError, ValueError):
        return None


@dataclass
class _Reading:
    wall: float
    cpu: float
    stall_us: int | None
    involuntary: int

    @classmethod
    def now(cls) -> _Reading:
        return cls(time.perf_counter(), time.process_time(), cpu_stall_us(),
                   resource.getrusage(resource.RUSAGE_SELF).ru_nivcsw)


def usable_cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # not Linux
        return os.cpu_count() or 1


class LoadMonitor:
    """Measures the machine's load over a block: ``with LoadMonitor() as load: ...``,
    then ``load.result()``. ``host_bound_cpu``: whether the process's CPU share says
    anything (True on the LLVM backend, whose worker threads run the kernels)."""

    def __init__(self, host_bound_cpu: bool = True) -> None:
        self.host_bound_cpu = host_bound_cpu
        self._start: _Reading | None = None
        self._end: _Reading | None = None

    def __enter__(self) -> LoadMonitor:
        self._start = _Reading.now()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._end = _Reading.now()

    def result(self) -> dict[str, Any]:
        """The window's figures and verdict (``loaded``: True, False or None = unknown)."""
        assert self._start is not None and self._end is not None, "use as a context manager"
        start, end = self._start, self._end
        wall = max(end.wall - start.wall, 1e-9)
        cores = usable_cores()
        stall = (None if start.stall_us is None or end.stall_us is None
                 else (end.stall_us - start.stall_us) * 1e-6 / wall)
        cpu_share = (end.cpu - start.cpu) / wall / cores
        return {
            "wall_s": wall,
            "cpu_stall_fraction": stall,
            "process_cpu_share": cpu_share,
            "cores": cores,
            "involuntary_switches_per_s": (end.involuntary - start.involuntary) / wall,
            **judge(stall, cpu_share if self.host_bound_cpu else None),
        }


def stall_text(stall: float) -> str:
    """How long tasks waited for a core, as a share of the window: at most all of it.
    The kernel adds to its stall counter in steps, so over a window of a few
    milliseconds it can advance by more than the window (7.7 times it, measured on the
    shared 2-core machine), which reads as the whole window, never as '773 %'."""
    if stall >= 1.0:
        return "tasks waited for a core all of the time"
    return f"tasks waited for a core {100 * stall:.0f} % of the time"


def judge(stall: float | None, cpu_share: float | None) -> dict[str, Any]:
    """``loaded`` and ``reasons`` from the stall share (preferred) or the CPU share."""
    if stall is not None:
        loaded = stall > STALL_LIMIT
        reason = (f"other work held the CPU: {stall_text(stall)} "
                  f"(limit {100 * STALL_LIMIT:.0f} %)")
        return {"loaded": loaded, "basis": "cpu pressure", "reasons": [reason] if loaded else []}
    if cpu_share is not None:
        loaded = cpu_share < CPU_SHARE_LIMIT
        reason = (f"the process got {100 * cpu_share:.0f} % of the cores (below "
                  f"{100 * CPU_SHARE_LIMIT:.0f} %): other work held the CPU")
        return {"loaded": loaded, "basis": "process cpu share",
                "reasons": [reason] if loaded else []}
    return {"loaded": None, "basis": "unknown",
            "reasons": ["no CPU pressure information on this machine: load unknown"]}
