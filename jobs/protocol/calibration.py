"""Equal-time calibration: the largest knob (N_c, spp) whose frame time fits a budget.

Papers compare methods at matched time per frame; which N_c or spp that is
depends on the device, so it is measured on the device that runs the
comparison, never assumed from the papers' GPU numbers, and the measurement
is stored with the result it justified (docs/protocol.md, "Equal time").

How it measures, because these machines are shared and their speed drifts:

- the measurements are interleaved in rounds; each round times the budget
  (when it is measured, e.g. PT at some spp or an NRC point) and then the
  candidates still in play, in ascending order on even rounds and descending
  on odd ones, so a slow drift of the machine affects every value alike; each
  candidate in play is timed in ``rounds`` rounds (:func:`search`);
- a candidate is out of play when its frame time, or the one a log-log line
  through the medians timed so far predicts for it, exceeds
  :data:`PREDICTION_CUT` x the budget (it cannot fit, and timing it would cost
  more than the rest of the search); for a knob whose frame time grows with its
  value (``monotone``: spp), also every candidate above one whose fastest round
  is over the limit by more than the allowed spread, and every candidate below
  one whose slowest round is under it by as much (neither can be chosen). A
  knob that is not monotone (with BTH, more neural samples can stop paths
  earlier) has every other candidate timed, also past a slow one;
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
- a probe taken on a loaded machine (renderers.load) is left out and taken again,
  up to :data:`LOADED_RETRIES` times (each left-out probe is listed in ``left_out``);
  when every try was loaded the calibration stops (:class:`LoadedMachineError`),
  unless the budget allows loaded timings (``allow_loaded``: then they are used, and
  ``loaded`` says that other work held the CPU during a probe); an unstable or loaded
  calibration says what to do about it (:data:`ADVICE`);
- what the calibration cost is stored with it: wall seconds, probes per round
  and timed frames.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from functools import cache
from typing import Any

import numpy as np

#: Default number of interleaved rounds and the allowed spread (fraction of the budget).
DEFAULT_ROUNDS = 3
DEFAULT_MAX_SPREAD = 0.1
#: A candidate whose frame time (measured, else predicted) exceeds this many times the
#: budget plus its tolerance (what still fits) is not timed (again).
PREDICTION_CUT = 4.0
#: What to do about a calibration whose timings cannot be trusted.
ADVICE = ("what to do: calibrate again with nothing else running on the machine (the load "
          "flag says whether something was), or with more rounds (a time budget's 'rounds') "
          "or a tolerance at least as wide as the spread ('tolerance_ms', sweep "
          "--tolerance-ms); until then the chosen value may be one candidate off")
#: How many times a probe taken on a loaded machine is taken again before giving up.
LOADED_RETRIES = 2


class LoadedMachineError(ValueError):
    """Every try of a calibration probe ran on a loaded machine, and the budget does
    not allow loaded timings."""


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
    monotone: bool = False          # the search stopped above a candidate clearly over budget
    not_timed: dict[int, str] = field(default_factory=dict)  # knob value -> why not
    wall_s: float = 0.0             # seconds the calibration took
    probes_per_round: list[int] = field(default_factory=list)  # renders timed (budget included)
    timed_frames: int | None = None  # frames timed in all (None: frames per probe unknown)
    left_out: list[str] = field(default_factory=list)  # probes left out: loaded machine

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
        data["not_timed"] = {str(k): v for k, v in self.not_timed.items()}
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


def predicted_seconds(medians: dict[int, float], value: int) -> float | None:
    """The frame time at knob ``value`` from the medians of the candidates timed so
    far: the least-squares line log t = c + k log v (None from fewer than two).

    For a frame costing a + b v (a, b >= 0), log t is convex in log v, so beyond
    the timed values the line falls below the cost: the cut errs towards timing."""
    positive = {v: t for v, t in medians.items() if t > 0}
    if len(positive) < 2:
        return None
    slope, intercept = np.polyfit(np.log(list(positive)), np.log(list(positive.values())), 1)
    return float(np.exp(intercept + slope * np.log(value)))


@dataclass
class Search:
    """The timings of :func:`search`: per candidate, of the budget, their order, the
    renders timed in each round and why a candidate was not timed when its turn came."""

    times: dict[int, list[float]]
    leads: list[float] = field(default_factory=list)
    order: list[str] = field(default_factory=list)
    probes_per_round: list[int] = field(default_factory=list)
    passed_over: dict[int, str] = field(default_factory=dict)


def seconds_of(value: Any, what: str) -> float:
    """A probe's seconds per frame, refused when not a finite non-negative number."""
    seconds = float(value)
    if not (math.isfinite(seconds) and seconds >= 0):
        raise ValueError(f"the probe of {what} timed {seconds} s per frame")
    return seconds


def search(knob: str, values: Sequence[int], measure: Callable[[int], float],
           budget: float | Callable[[], float], *, tolerance_s: float, rounds: int,
           max_spread: float, monotone: bool) -> Search:
    """Time the ascending ``values`` in interleaved rounds (module docstring): each
    round times the budget when it is a function, then, in ascending order on even
    rounds and descending on odd ones, every candidate timed fewer than ``rounds``
    times that is still in play when its turn comes. Rounds go on while a candidate in
    play lacks timings (one that came back into play because a slow first timing was
    not repeated gets its rounds after the others) and stop after a round that timed
    no candidate."""
    fixed = not callable(budget)
    state = Search(times={v: [] for v in values})

    def budget_s() -> float:
        return float(budget) if fixed else float(np.median(state.leads))  # type: ignore[arg-type]

    def passed_over(value: int) -> str | None:
        """Why ``value`` is out of play now (None: it is in play)."""
        limit = budget_s() + tolerance_s
        margin = max(tolerance_s, max_spread * budget_s())
        timed = {v: t for v, t in state.times.items() if t}
        if monotone:
            clearly_under = [v for v, t in timed.items() if max(t) < limit - margin]
            if clearly_under and value < max(clearly_under):
                return (f"below {knob} {max(clearly_under)}, which is under the budget by "
                        "more than the allowed spread in every round")
            clearly_over = [v for v, t in timed.items() if min(t) > limit + margin]
            if clearly_over and value > min(clearly_over):
                return (f"{knob} {min(clearly_over)} is over the budget by more than the "
                        f"allowed spread in every round, and the cost grows with {knob}")
        medians = {v: float(np.median(t)) for v, t in timed.items()}
        expected = medians[value] if value in medians else predicted_seconds(medians, value)
        if expected is not None and expected > PREDICTION_CUT * limit:
            how = "timed" if value in medians else "predicted"
            return (f"{how} {1e3 * expected:.3g} ms per frame, over {PREDICTION_CUT:g} x the "
                    f"budget and its tolerance")
        return None

    def due(value: int) -> bool:
        return len(state.times[value]) < rounds and passed_over(value) is None

    index = 0
    while index == 0 or any(due(v) for v in values):
        probes = 0
        if not fixed:
            state.leads.append(seconds_of(budget(), "the budget"))  # type: ignore[operator]
            state.order.append("budget")
            probes += 1
        timed_any = False
        for value in values if index % 2 == 0 else reversed(values):
            if len(state.times[value]) >= rounds:
                continue
            reason = passed_over(value)
            if reason is not None:
                state.passed_over[value] = reason
                continue
            state.times[value].append(seconds_of(measure(value), f"{knob} {value}"))
            state.order.append(f"{knob}={value}")
            probes, timed_any = probes + 1, True
        state.probes_per_round.append(probes)
        index += 1
        if not timed_any:
            break
    return state


def calibrate(knob: str, candidates: Sequence[int], measure: Callable[[int], float],
              budget: float | Callable[[], float], *, budget_source: str,
              tolerance_s: float = 0.0, device_key: str = "", rounds: int = DEFAULT_ROUNDS,
              max_spread: float = DEFAULT_MAX_SPREAD, monotone: bool = False,
              probe_frames: int | None = None) -> Calibration:
    """Time the candidates (``measure(value)``: seconds per frame) and the budget
    (a number, or a function measuring it) in interleaved rounds (:func:`search`;
    ``monotone``: the frame time grows with the knob) and choose the largest
    candidate whose median fits median(budget) + tolerance (module docstring). When
    none fits, the smallest is chosen and ``fits`` is False. ``probe_frames``: the
    frames each probe times (for the record's ``timed_frames``).
    """
    values = sorted(set(int(c) for c in candidates))
    if not values:
        raise ValueError("calibration needs at least one candidate")
    if rounds < 1:
        raise ValueError(f"calibration needs at least one round, got {rounds}")
    fixed = not callable(budget)
    if fixed and not budget > 0:
        raise ValueError(f"the time budget must be positive, got {budget}")
    started = time.perf_counter()
    state = search(knob, values, measure, budget, tolerance_s=tolerance_s, rounds=rounds,
                   max_spread=max_spread, monotone=monotone)
    times = {v: t for v, t in state.times.items() if t}
    budgets = state.leads
    budget_s = float(budget) if fixed else float(np.median(budgets))  # type: ignore[arg-type]
    if not budget_s > 0:
        raise ValueError(f"the measured time budget must be positive, got {budget_s}")

    limit = budget_s + tolerance_s
    probes = sum(state.probes_per_round)
    record = Calibration(
        knob=knob, budget_s=budget_s, budget_source=budget_source, tolerance_s=tolerance_s,
        measured_s={v: float(np.median(t)) for v, t in times.items()},
        spread_s={v: [min(t), max(t)] for v, t in times.items()},
        budget_spread_s=None if fixed else [min(budgets), max(budgets)],
        rounds=rounds, order=state.order, device_key=device_key, monotone=monotone,
        not_timed={v: state.passed_over[v] for v in values if v not in times},
        wall_s=time.perf_counter() - started, probes_per_round=state.probes_per_round,
        timed_frames=None if probe_frames is None else probes * probe_frames)
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
    if calibration.get("left_out"):
        found.append(f"{len(calibration['left_out'])} probe(s) left out: machine loaded")
    return found


class LoadLog:
    """Collects the load of every probe (:func:`probe_timings`) of a calibration, and the
    probes left out for a loaded machine."""

    def __init__(self, allow_loaded: bool = False) -> None:
        self.loads: list[dict[str, Any] | None] = []
        self.allow_loaded = allow_loaded
        self.left_out: list[str] = []

    def seconds(self, timings: dict[str, Any]) -> float:
        """The probe's frame time, keeping its load."""
        self.loads.append(timings.get("load"))
        return timings["frame_median_s"]

    def quiet_seconds(self, probe: Callable[[], dict[str, Any]], what: str) -> float:
        """The frame time of ``probe()`` (its timings) on a quiet machine: a loaded try is
        left out (and listed) and taken again, up to :data:`LOADED_RETRIES` times;
        LoadedMachineError when every try was loaded. With ``allow_loaded`` the first try
        counts whatever the load."""
        for _ in range(LOADED_RETRIES + 1):
            timings = probe()
            load = timings.get("load") or {}
            if self.allow_loaded or not load.get("loaded"):
                return self.seconds(timings)
            self.left_out.append(f"{what}: {1e3 * timings['frame_median_s']:.3g} ms left out, "
                                 f"machine loaded ({'; '.join(load.get('reasons', []))})")
        raise LoadedMachineError(
            f"equal-time calibration stopped: {LOADED_RETRIES + 1} probes of {what} in a row "
            "ran on a loaded machine (other work held the CPU), and a loaded timing would "
            "choose the knob for the load, not the method; run it again with nothing else "
            "running, or allow loaded timings (--allow-loaded; a time budget's or a "
            "sweep's 'allow_loaded')")

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
    log = LoadLog(budget.allow_loaded)

    def frame_seconds(probe: Any, spp: int, what: str) -> float:
        return log.quiet_seconds(lambda: probe_timings(scene, probe.method, probe.params, spp,
                                                       budget.probe_frames), what)

    budget_value: float | Callable[[], float]
    if budget.ms is not None:
        budget_value, source = budget.ms / 1e3, f"{budget.ms} ms per frame"
    else:
        baseline = job.baseline()
        budget_value = lambda: frame_seconds(  # noqa: E731
            baseline, budget.pt_spp, f"the budget (PT {budget.pt_spp} spp)")
        source = f"PT {budget.pt_spp} spp frame time (measured)"

    @cache
    def candidate(value: int) -> Any:
        """The job with knob ``value`` (derived once per value, whatever the rounds)."""
        return job.with_params(spec_knob.apply(spec.params, value))

    def measure(value: int) -> float:
        if knob == "spp":
            return frame_seconds(job, value, f"spp {value}")
        return frame_seconds(candidate(value), spec.spp, f"{knob} {value}")

    record = calibrate(knob, budget.candidates or default_candidates, measure, budget_value,
                       budget_source=source, tolerance_s=budget.tolerance_ms / 1e3,
                       device_key=device_key, rounds=budget.rounds,
                       max_spread=budget.max_spread, monotone=bool(spec_knob.monotone),
                       probe_frames=budget.probe_frames)
    record.note_load(log.merged())
    record.left_out = log.left_out
    if knob == "spp":
        return job.with_spec(time_budget=None, spp=record.chosen), record
    return candidate(record.chosen).with_spec(time_budget=None), record
