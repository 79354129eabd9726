"""Equal-time calibration: the largest knob (N_c, spp) whose frame time fits a budget.

Papers compare methods at matched time per frame (DESIGN.md, "Equal-time
protocol"); which N_c or spp that is depends on the device, so it is measured
on the device that runs the comparison, never assumed from the papers' GPU
numbers, and the measurement is stored with the result it justified.

The search walks the candidates upward and stops at the first that exceeds
the budget (plus a tolerance: the NIRC paper matches "within a 1 ms epsilon",
Sec. 6.3). That assumes the frame time grows with the knob, which holds for
spp and for N_c at a fixed termination policy (the policy, not N_c, decides
which paths query the cache); the record keeps every measured time, so a
violation would be visible.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass
class Calibration:
    """The outcome of one calibration (stored with the result it was made for)."""

    knob: str                       # 'nc' or 'spp'
    budget_s: float                 # seconds per frame to fit
    budget_source: str              # e.g. 'NRC frame time at rBias2 1.2e-3', 'PT 2 spp'
    tolerance_s: float
    measured_s: dict[int, float] = field(default_factory=dict)  # knob value -> s/frame
    chosen: int = 0
    fits: bool = False              # False: even the smallest candidate is over budget
    device_key: str = ""

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["measured_s"] = {str(k): v for k, v in self.measured_s.items()}
        return data


def calibrate(knob: str, candidates: Sequence[int], measure: Callable[[int], float],
              budget_s: float, *, budget_source: str, tolerance_s: float = 0.0,
              device_key: str = "") -> Calibration:
    """Measure ``measure(value)`` (seconds per frame) for ascending candidates until
    one exceeds ``budget_s + tolerance_s``; choose the largest that fit.

    When none fits, the smallest candidate is chosen and ``fits`` is False.
    """
    values = sorted(set(int(c) for c in candidates))
    if not values:
        raise ValueError("calibration needs at least one candidate")
    if not budget_s > 0:
        raise ValueError(f"the time budget must be positive, got {budget_s}")
    record = Calibration(knob=knob, budget_s=budget_s, budget_source=budget_source,
                         tolerance_s=tolerance_s, device_key=device_key)
    for value in values:
        seconds = float(measure(value))
        record.measured_s[value] = seconds
        if seconds > budget_s + tolerance_s:
            break
    fitting = [v for v, s in record.measured_s.items() if s <= budget_s + tolerance_s]
    record.fits = bool(fitting)
    record.chosen = max(fitting) if fitting else values[0]
    return record
