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


#: The knob each method is calibrated by, and its default candidates.
KNOBS = {"pt": ("spp", [1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256, 384,
                        512]),
         "nirc": ("nc", [1, 2, 4, 8, 16, 32])}


def calibrate_job(spec: Any, scene: Any, device_key: str) -> tuple[Any, Calibration]:
    """Calibrate ``spec``'s knob to its ``time_budget`` on this device.

    Returns the spec with the chosen spp (pt) or N_c (biased nirc) and no
    budget, and the calibration record. Probes render one seed for
    ``probe_frames`` frames (caches without pre-training: the per-frame cost,
    online training included, does not depend on how trained the cache is).
    """
    from renderers.methods import MethodError, get_method, parse_params

    budget = spec.time_budget
    if spec.method not in KNOBS or (spec.method == "nirc"
                                    and spec.params.get("estimator", "biased") != "biased"):
        raise MethodError(f"no equal-time knob for method '{spec.method}' with these "
                          "parameters: time budgets calibrate pt (spp) and biased nirc (N_c)")
    knob, default_candidates = KNOBS[spec.method]

    def frame_seconds(method: str, params: dict[str, Any], spp: int) -> float:
        values = parse_params(method, params)
        if "pretrain_frames" in type(values).model_fields:
            values = values.model_copy(update={"pretrain_frames": 0})
        output = get_method(method).render(
            scene, values, seed_parts=("calibration", method, values.model_dump(mode="json")),
            spp=spp, frames=budget.probe_frames)
        return output.timings["frame_median_s"]

    if budget.ms is not None:
        budget_s, source = budget.ms / 1e3, f"{budget.ms} ms per frame"
    else:
        pt_params = {"max_depth": spec.max_depth()}
        budget_s = frame_seconds("pt", pt_params, budget.pt_spp)
        source = f"PT {budget.pt_spp} spp frame time (measured)"

    def measure(value: int) -> float:
        if knob == "spp":
            return frame_seconds(spec.method, spec.params, value)
        return frame_seconds(spec.method, {**spec.params, "nc": [value]}, spec.spp)

    record = calibrate(knob, budget.candidates or default_candidates, measure, budget_s,
                       budget_source=source, tolerance_s=budget.tolerance_ms / 1e3,
                       device_key=device_key)
    update: dict[str, Any] = {"time_budget": None}
    if knob == "spp":
        update["spp"] = record.chosen
    else:
        update["params"] = {**spec.params, "nc": [record.chosen]}
    return spec.model_copy(update=update), record
