"""Equal-time calibration: the largest knob (N_c, spp) whose frame time fits a budget.

Papers compare methods at matched time per frame; which N_c or spp that is
depends on the device, so it is measured on the device that runs the
comparison, never assumed from the papers' GPU numbers, and the measurement
is stored with the result it justified (docs/protocol.md, "Equal time").

How it measures, because these machines are shared and their speed drifts:

- every candidate is timed, not only until the first one over budget: the
  frame time need not grow with the knob (with BTH, more neural samples can
  stop paths earlier);
- the measurements are interleaved in ``rounds`` rounds; each round times the
  budget (when it is measured, e.g. PT at some spp or an NRC point) and then
  every candidate, in ascending order on even rounds and descending on odd
  ones, so a slow drift of the machine affects every value alike;
- the decision uses medians over rounds: the chosen value is the largest
  candidate whose median fits median(budget) + tolerance;
- the spread (min and max over rounds) of every timing is stored. The
  calibration is flagged ``unstable`` (with the reasons) when the budget's
  spread, or the spread of a candidate whose rounds disagree about fitting,
  exceeds the allowed spread max(tolerance, ``max_spread`` x budget): the
  choice then depends on the noise of the machine;
- ``capped`` says that the largest candidate fits: the true equal-time value
  may be larger than any candidate tried; ``fits`` False says that not even
  the smallest fits (it is then chosen);
- ``loaded`` says that other work held the CPU during a probe (renderers.load);
  an unstable or loaded calibration says what to do about it (:data:`ADVICE`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from functools import cache
from typing import Any

import numpy as np

#: Default number of interleaved rounds and the allowed spread (fraction of the budget).
DEFAULT_ROUNDS = 3
DEFAULT_MAX_SPREAD = 0.1
#: What to do about a calibration whose timings cannot be trusted.
ADVICE = ("what to do: calibrate again with nothing else running on the machine (the load "
          "flag says whether something was), or with more rounds (a time budget's 'rounds') "
          "or a tolerance at least as wide as the spread ('tolerance_ms', sweep "
          "--tolerance-ms); until then the chosen value may be one candidate off")


@dataclass
class Calibration:
    """The outcome of one calibration (stored with the result it was made for)."""

    knob: str                       # 'nc' or 'spp'
    budget_s: float                 # seconds per frame to fit (median over rounds if measured)
    budget_source: str              # e.g. 'NRC frame time at eps 0.3', 'PT 2 spp'
    tolerance_s: float
    measured_s: dict[int, float] = field(default_factory=dict)  # knob value -> median s/frame
    spread_s: dict[int, list[float]] = field(default_factory=dict)  # knob value -> [min, max]
    budget_spread_s: list[float] | None = None  # [min, max] of a measured budget, else None
    rounds: int = 1
    chosen: int = 0
    fits: bool = False              # False: even the smallest candidate is over budget
    capped: bool = False            # True: the largest candidate fits (the top of the range)
    unstable: bool = False          # True: the timings' spread could change the choice
    loaded: bool | None = None      # other work held the CPU during a probe (None: unknown)
    reasons: list[str] = field(default_factory=list)
    order: list[str] = field(default_factory=list)  # the measurement order ('budget', 'nc=4')
    device_key: str = ""

    def note_load(self, load: dict[str, Any] | None) -> None:
        """Record the machine's load over the probes (renderers.timing.merge_loads)."""
        if load is None:
            return
        self.loaded = load["loaded"]
        if self.loaded:
            self.reasons += [f"loaded: {reason}" for reason in load["reasons"]]
            if ADVICE not in self.reasons:
                self.reasons.append(ADVICE)

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["measured_s"] = {str(k): v for k, v in self.measured_s.items()}
        data["spread_s"] = {str(k): v for k, v in self.spread_s.items()}
        return data


@dataclass
class Rounds:
    """Timings of :func:`interleaved_rounds`: per value, of the lead, and their order."""

    times: dict[Any, list[Any]]
    lead: list[float]
    order: list[str]


def interleaved_rounds(values: Sequence[Any], measure: Callable[[Any], Any], rounds: int, *,
                       name: Callable[[Any], str] = str,
                       lead: Callable[[], float] | None = None) -> Rounds:
    """Time every value (``measure(value)``: seconds) in ``rounds`` rounds, ascending
    in even rounds and descending in odd ones, so a slow drift of the machine affects
    every value alike; ``lead`` (e.g. a measured budget) is timed first in each round.
    ``order`` records the measurements ('budget' for the lead, ``name(value)``);
    ``times`` holds what ``measure`` returned (seconds, or a richer record)."""
    timed = Rounds(times={v: [] for v in values}, lead=[], order=[])
    for index in range(rounds):
        if lead is not None:
            timed.lead.append(float(lead()))
            timed.order.append("budget")
        for value in values if index % 2 == 0 else reversed(values):
            timed.times[value].append(measure(value))
            timed.order.append(name(value))
    return timed


def calibrate(knob: str, candidates: Sequence[int], measure: Callable[[int], float],
              budget: float | Callable[[], float], *, budget_source: str,
              tolerance_s: float = 0.0, device_key: str = "", rounds: int = DEFAULT_ROUNDS,
              max_spread: float = DEFAULT_MAX_SPREAD) -> Calibration:
    """Time every candidate (``measure(value)``: seconds per frame) and the budget
    (a number, or a function measuring it) in ``rounds`` interleaved rounds and
    choose the largest candidate whose median fits median(budget) + tolerance
    (module docstring). When none fits, the smallest is chosen and ``fits`` is False.
    """
    values = sorted(set(int(c) for c in candidates))
    if not values:
        raise ValueError("calibration needs at least one candidate")
    if rounds < 1:
        raise ValueError(f"calibration needs at least one round, got {rounds}")
    fixed = not callable(budget)
    if fixed and not budget > 0:
        raise ValueError(f"the time budget must be positive, got {budget}")
    timed = interleaved_rounds(values, measure, rounds, name=lambda v: f"{knob}={v}",
                               lead=None if fixed else budget)
    times, budgets, order = timed.times, timed.lead, timed.order
    budget_s = float(budget) if fixed else float(np.median(budgets))
    if not budget_s > 0:
        raise ValueError(f"the measured time budget must be positive, got {budget_s}")

    limit = budget_s + tolerance_s
    record = Calibration(
        knob=knob, budget_s=budget_s, budget_source=budget_source, tolerance_s=tolerance_s,
        measured_s={v: float(np.median(t)) for v, t in times.items()},
        spread_s={v: [min(t), max(t)] for v, t in times.items()},
        budget_spread_s=None if fixed else [min(budgets), max(budgets)],
        rounds=rounds, order=order, device_key=device_key)
    fitting = [v for v, s in record.measured_s.items() if s <= limit]
    record.fits = bool(fitting)
    record.chosen = max(fitting) if fitting else values[0]
    record.capped = record.fits and record.chosen == values[-1]
    if record.capped:
        record.reasons.append(f"capped: the largest candidate ({knob} {values[-1]}) fits the "
                              "budget; a larger one might too")

    allowed = max(tolerance_s, max_spread * budget_s)
    if record.budget_spread_s is not None:
        lo, hi = record.budget_spread_s
        if hi - lo > allowed:
            record.unstable = True
            record.reasons.append(f"unstable: the budget's spread {1e3 * (hi - lo):.3g} ms "
                                  f"exceeds {1e3 * allowed:.3g} ms")
    for value, (lo, hi) in record.spread_s.items():
        # Only a candidate whose rounds disagree about fitting can change the choice.
        if hi - lo > allowed and lo <= limit < hi:
            record.unstable = True
            record.reasons.append(f"unstable: {knob} {value} spreads over "
                                  f"{1e3 * lo:.3g}..{1e3 * hi:.3g} ms across the limit "
                                  f"{1e3 * limit:.3g} ms (allowed spread {1e3 * allowed:.3g} ms)")
    if record.unstable:
        record.reasons.append(ADVICE)
    return record


def probe_timings(scene: Any, method: str, params: Any, spp: int, frames: int) -> dict[str, Any]:
    """The timings (renderers.timing.summarize) of one seed of ``method`` with validated
    ``params`` rendering ``frames`` frames of ``scene`` (online training included;
    caches without pre-training: the per-frame cost does not depend on how trained the
    cache is)."""
    from renderers.methods import get_method

    if "pretrain_frames" in type(params).model_fields:
        params = params.model_copy(update={"pretrain_frames": 0})
    output = get_method(method).render(
        scene, params, seed_parts=("calibration", method, params.model_dump(mode="json")),
        spp=spp, frames=frames)
    return output.timings


def caveats(calibration: dict[str, Any]) -> list[str]:
    """What a stored calibration record (``Calibration.to_json()``) says against trusting
    its choice, in a few words each: capped, unstable, loaded (records stored before a
    flag existed lack it)."""
    found = []
    if calibration.get("capped"):
        found.append(f"calibration capped: {calibration['knob']} {calibration['chosen']} is "
                     "the largest candidate; a larger one might fit")
    if calibration.get("unstable"):
        found.append("calibration unstable: the machine's timing noise could change the "
                     "choice")
    if calibration.get("loaded"):
        found.append("machine loaded during the calibration")
    return found


class LoadLog:
    """Collects the load of every probe (:func:`probe_timings`) of a calibration."""

    def __init__(self) -> None:
        self.loads: list[dict[str, Any] | None] = []

    def seconds(self, timings: dict[str, Any]) -> float:
        """The probe's frame time, keeping its load."""
        self.loads.append(timings.get("load"))
        return timings["frame_median_s"]

    def merged(self) -> dict[str, Any] | None:
        from renderers.timing import merge_loads

        return merge_loads(self.loads)


def knob_of(spec: Any) -> Any:
    """The equal-time knob of ``spec``'s method with its parameters (MethodError if none)."""
    from renderers.methods import METHODS, MethodError

    method = METHODS.get(spec.method)
    knob = method.knob if method is not None else None
    if knob is None or not knob.usable(spec.params):
        knobs = " and ".join(f"{m.knob.requirement or name} ({m.knob.name})"
                          for name, m in METHODS.items() if m.knob is not None)
        raise MethodError(f"no equal-time knob for method '{spec.method}' with these "
                          f"parameters: time budgets calibrate {knobs}")
    return knob


def calibrate_job(job: Any, scene: Any, device_key: str) -> tuple[Any, Calibration]:
    """Calibrate the knob of ``job`` (a :class:`jobs.protocol.job.RenderJob`) to its
    spec's ``time_budget`` on this device.

    The knob is the method's (its ``Method.knob``): spp, or a parameter the
    method sets (N_c at v1 for biased nirc). Returns the job with the chosen
    value and no budget, and the calibration record. Probes render one seed for ``probe_frames`` frames
    (caches without pre-training: the per-frame cost, online training
    included, does not depend on how trained the cache is). A PT budget is
    re-measured in every round, interleaved with the candidates. Each candidate is
    a job derived from ``job`` (the job module validates it); the probes take its
    typed parameters.
    """
    spec = job.spec
    budget = spec.time_budget
    spec_knob = knob_of(spec)
    knob, default_candidates = spec_knob.name, list(spec_knob.candidates)
    log = LoadLog()

    def frame_seconds(probe: Any, spp: int) -> float:
        return log.seconds(probe_timings(scene, probe.method, probe.params, spp,
                                         budget.probe_frames))

    budget_value: float | Callable[[], float]
    if budget.ms is not None:
        budget_value, source = budget.ms / 1e3, f"{budget.ms} ms per frame"
    else:
        baseline = job.baseline()
        budget_value = lambda: frame_seconds(baseline, budget.pt_spp)  # noqa: E731
        source = f"PT {budget.pt_spp} spp frame time (measured)"

    @cache
    def candidate(value: int) -> Any:
        """The job with knob ``value`` (derived once per value, whatever the rounds)."""
        return job.with_params(spec_knob.apply(spec.params, value))

    def measure(value: int) -> float:
        if knob == "spp":
            return frame_seconds(job, value)
        return frame_seconds(candidate(value), spec.spp)

    record = calibrate(knob, budget.candidates or default_candidates, measure, budget_value,
                       budget_source=source, tolerance_s=budget.tolerance_ms / 1e3,
                       device_key=device_key, rounds=budget.rounds,
                       max_spread=budget.max_spread)
    record.note_load(log.merged())
    if knob == "spp":
        return job.with_spec(time_budget=None, spp=record.chosen), record
    return candidate(record.chosen).with_spec(time_budget=None), record
