"""The per-stage cost model: what a frame would cost at another resolution on this device.

Each timed stage of a method's frame (renderers.timing) costs a + b * size, where
size is the work the stage does in a frame: pixels x spp for the stages that trace
or shade the image, or the unit the method declares (``Method.stage_sizes``: the
training records and paths of a caching method, which stay at their floor
max(floor, 3.16 % of the pixels) in small frames; one unit for work of a fixed size,
such as a visibility cache's training points). a is the stage's fixed cost (Python
tracing, launches, fixed-size work), b its cost per unit.

a and b are fitted by weighted least squares from probes of several resolutions (64²,
128², 256² by default: where b * size is not negligible), timed in interleaved rounds
(jobs.protocol.calibration.interleaved_rounds), with Student-t intervals. The weights
fit relative errors (:func:`fit_line`): the timing noise is a fraction of the frame's
time, so the largest probe is the noisiest and must not decide the line. A stage
held at a floor in every probe says nothing about b; the probes then also scale the
method's floors (``Method.scale_floors``), so its size varies. Kernel time
(renderers.timing) is modelled the same way, so a projection says how much of the
projected frame is harness.

A projection to another resolution is labelled as one: it holds for this device,
its interval is that of the fitted mean (not of one frame), the stages' intervals
are added (conservative: the stages share their probes), and it extrapolates the
sizes beyond the largest probe by the factor it reports. Docs: docs/timing.md.
"""

from __future__ import annotations

import gc
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from statistics import median_low
from typing import Any

import numpy as np

from jobs.protocol.calibration import DEFAULT_MAX_SPREAD, DEFAULT_ROUNDS, interleaved_rounds
from renderers.timing import OTHER, FrameTime, kernel_frames, merge_loads, wall_frames

CONFIDENCE = 0.95
#: Resolutions (square) and floor factors the probes use by default.
DEFAULT_RESOLUTIONS = (64, 128, 256)
DEFAULT_FLOOR_FACTORS = (1.0, 4.0, 16.0)
PIXEL_UNIT = "pixels x spp"


@dataclass(frozen=True)
class LinearFit:
    """seconds = intercept + slope * size, fitted over ``n`` samples.

    ``slope`` is None when every sample had the same size (then ``intercept`` is their
    mean, valid at that size only: ``sizes``). Intervals are Student-t at
    :data:`CONFIDENCE`; ``covariance`` is that of (intercept, slope).
    """

    intercept: float
    intercept_ci: tuple[float, float]
    slope: float | None
    slope_ci: tuple[float, float] | None
    n: int
    sizes: tuple[float, ...]            # the distinct sizes fitted
    se_intercept: float
    se_slope: float | None
    covariance: float | None
    t_quantile: float

    def predict(self, size: float) -> Prediction:
        """The fitted mean at ``size``, with its interval; None where the fit cannot tell
        (one size only, and another is asked for)."""
        if self.slope is None or self.se_slope is None or self.covariance is None:
            if not np.isclose(size, self.sizes[0]):
                return Prediction(None, None, f"size held at {self.sizes[0]:g} in every probe")
            return Prediction(self.intercept, self.intercept_ci, "")
        value = self.intercept + self.slope * size
        variance = (self.se_intercept ** 2 + size ** 2 * self.se_slope ** 2
                    + 2 * size * self.covariance)
        half = self.t_quantile * float(np.sqrt(max(variance, 0.0)))
        return Prediction(value, (value - half, value + half), "")

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class Prediction:
    value: float | None
    ci: tuple[float, float] | None
    note: str


def fit_line(sizes: Sequence[float], seconds: Sequence[float],
             confidence: float = CONFIDENCE) -> LinearFit:
    """Weighted least squares a + b * size with Student-t intervals; a constant (the
    mean) when every size is the same.

    Weights: 1 / m², m the median of the samples of the same size (floored at 1e-3 of
    the largest m, for stages absent at some size). A machine's timing noise is a
    fraction of a frame's time (a slower machine slows every kernel alike; the
    calibration and the probes' flags bound spreads as fractions of the median), so
    the samples' spread grows with the size: unweighted, the largest probe's noise
    would decide the intercept and the intervals would claim more than they hold.
    Weighted, every sample counts by its relative error, and with weights known up
    to a factor cov(a, b) = s² (XᵀWX)⁻¹, s² = Σ w r² / (n - 2)."""
    from scipy import stats  # ~1 s to import: only where a model is fitted

    x = np.asarray(sizes, dtype=float)
    y = np.asarray(seconds, dtype=float)
    if x.size != y.size or x.size < 2:
        raise ValueError(f"a fit needs at least two samples of equal length, got {x.size}, "
                         f"{y.size}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("a fit of non-finite sizes or times")
    distinct = tuple(float(v) for v in np.unique(x))
    level = (1 + confidence) / 2
    if len(distinct) == 1:
        t = float(stats.t.ppf(level, x.size - 1))
        mean = float(y.mean())
        se = float(y.std(ddof=1) / np.sqrt(y.size))
        return LinearFit(mean, (mean - t * se, mean + t * se), None, None, int(x.size),
                         distinct, se, None, None, t)
    if x.size < 3:
        raise ValueError("a straight line through two samples has no interval: probe more")
    medians = {v: float(np.median(y[x == v])) for v in distinct}
    scale = np.abs(np.array([medians[v] for v in x.tolist()]))
    scale = np.maximum(scale, 1e-3 * scale.max()) if scale.max() > 0 else np.ones_like(y)
    root_w = 1 / scale
    # Sizes in units of the largest keep XᵀWX well conditioned: b = b' / unit.
    unit = float(np.abs(x).max())
    design = np.column_stack([np.ones_like(x), x / unit]) * root_w[:, None]
    (a, b_scaled), *_ = np.linalg.lstsq(design, y * root_w, rcond=None)
    residual = (y - a - b_scaled * x / unit) * root_w
    cov = float(residual @ residual) / (x.size - 2) * np.linalg.inv(design.T @ design)
    t = float(stats.t.ppf(level, x.size - 2))
    b = b_scaled / unit
    se_a, se_b = float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1])) / unit
    return LinearFit(float(a), (a - t * se_a, a + t * se_a), float(b),
                     (b - t * se_b, b + t * se_b), int(x.size), distinct, se_a, se_b,
                     float(cov[0, 1]) / unit, t)


@dataclass(frozen=True)
class Probe:
    """One probe configuration: a square resolution and a factor on the method's floors."""

    resolution: int
    floor_factor: float = 1.0

    def label(self) -> str:
        floors = "" if self.floor_factor == 1 else f", floors x{self.floor_factor:g}"
        return f"{self.resolution}x{self.resolution}{floors}"


@dataclass
class ProbeSample:
    """One timed probe: per stage (and 'other'), its size, the median wall seconds over
    the probe's wall frames, and the median kernel and harness seconds over its kernel
    frames (each kernel frame's own wall less its own kernels: renderers.timing); the
    stage total of the median frame."""

    probe: Probe
    sizes: dict[str, float]
    wall_s: dict[str, float]
    kernel_s: dict[str, float] | None
    frame_s: float
    load: dict[str, Any] | None = None
    harness_s: dict[str, float] | None = None


def sample_of(probe: Probe, frames: Sequence[FrameTime], sizes: dict[str, float],
              load: dict[str, Any] | None = None) -> ProbeSample:
    """A :class:`ProbeSample` from a probe's timed frames; ``sizes`` per stage. Wall
    times over its wall frames, kernel and harness times over its kernel frames
    (renderers.timing)."""
    names = sorted({name for f in frames for name in f.parts()})
    walls, kernels = wall_frames(frames), kernel_frames(frames)

    def over_kernel_frames(parts: Callable[[FrameTime], dict[str, float] | None]
                           ) -> dict[str, float] | None:
        return {name: median_low([(parts(f) or {}).get(name, 0.0) for f in kernels])
                for name in names} if kernels else None

    return ProbeSample(
        probe, {name: sizes[name] for name in names},
        {name: median_low([f.parts().get(name, 0.0) for f in walls]) for name in names},
        over_kernel_frames(FrameTime.kernel_parts),
        median_low([f.total_s for f in walls]), load,
        over_kernel_frames(FrameTime.harness_parts))


@dataclass
class StageModel:
    """One stage's fitted wall, kernel and harness time against its size."""

    stage: str
    unit: str
    wall: LinearFit
    kernel: LinearFit | None
    harness: LinearFit | None = None


@dataclass
class StageProjection:
    stage: str
    size: float
    wall: Prediction
    kernel: Prediction | None
    extrapolation: float        # size / the largest probed size
    harness: Prediction | None = None


@dataclass
class Projection:
    """A frame at ``width`` x ``height`` projected from this device's cost model."""

    width: int
    height: int
    device_key: str
    stages: list[StageProjection]
    frame_s: float | None                       # the stages' sum (seconds per frame)
    frame_ci: tuple[float, float] | None
    other_s: float | None                       # between the stages, reported apart
    kernel_s: float | None                      # the whole frame's kernel time
    harness_share: float | None                 # harness / (kernel + harness)
    notes: list[str] = field(default_factory=list)
    label: str = ""

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class CostModel:
    """The stages of one method configuration fitted from its probes on one device."""

    method: str
    spp: int
    device_key: str
    stages: dict[str, StageModel]
    samples: list[ProbeSample]
    rounds: int
    order: list[str]
    flags: list[str]
    load: dict[str, Any] | None
    size_of: Callable[[int], dict[str, float]] = field(repr=False, default=lambda _n: {})

    def project(self, width: int, height: int) -> Projection:
        """The frame at ``width`` x ``height`` (module docstring: what it means)."""
        sizes = self.size_of(width * height)
        largest = {name: max(s.sizes[name] for s in self.samples) for name in self.stages}
        stages, notes = [], list(self.flags)
        for name, model in self.stages.items():
            size = sizes[name]
            wall = model.wall.predict(size)
            kernel = model.kernel.predict(size) if model.kernel is not None else None
            harness = model.harness.predict(size) if model.harness is not None else None
            if wall.note:
                notes.append(f"{name}: {wall.note}, not projectable to {size:g}")
            elif wall.value is not None and wall.value < 0:
                notes.append(f"{name}: the fit goes below 0 at this size (its cost does "
                             "not grow measurably); counted as 0")
            stages.append(StageProjection(name, size, wall, kernel,
                                          size / largest[name] if largest[name] else 1.0,
                                          harness))
        def total(parts: list[Prediction | None]) -> tuple[float | None, tuple | None]:
            if any(p is None or p.value is None or p.ci is None for p in parts):
                return None, None
            values = [max(p.value, 0.0) for p in parts]     # type: ignore[union-attr]
            halves = [(p.ci[1] - p.ci[0]) / 2 for p in parts]  # type: ignore[union-attr]
            return sum(values), (max(sum(values) - sum(halves), 0.0), sum(values) + sum(halves))

        proper = [s for s in stages if s.stage != OTHER]
        frame_s, frame_ci = total([s.wall for s in proper])
        other = next((s.wall for s in stages if s.stage == OTHER), None)
        other_s = None if other is None or other.value is None else max(other.value, 0.0)
        kernel_s, _ = total([s.kernel for s in stages])
        # The share of the kernel frames' own time outside their kernels: kernel and
        # harness are fitted over the same frames, never a wall frame's time less a
        # kernel frame's (renderers.timing), which can read below 0.
        harness_s, _ = total([s.harness for s in stages])
        spent = None if kernel_s is None or harness_s is None else kernel_s + harness_s
        reach = max(s.extrapolation for s in stages)
        if reach > 1.5:
            notes.append(f"extrapolated up to {reach:.3g}x beyond the largest probe")
        return Projection(
            width, height, self.device_key, stages, frame_s, frame_ci, other_s, kernel_s,
            None if not spent or harness_s is None else harness_s / spent, notes,
            label=f"projection to {width}x{height} from {self.device_key} (per-stage cost "
                  f"model, {CONFIDENCE:.0%} interval of the mean)")

    def to_json(self) -> dict[str, Any]:
        return {"method": self.method, "spp": self.spp, "device_key": self.device_key,
                "rounds": self.rounds, "order": self.order, "flags": self.flags,
                "load": self.load,
                "stages": {name: {"unit": m.unit, "wall": m.wall.to_json(),
                                  "kernel": m.kernel.to_json() if m.kernel else None,
                                  "harness": m.harness.to_json() if m.harness else None}
                           for name, m in self.stages.items()},
                "samples": [asdict(s) for s in self.samples]}


def fit_model(method: str, spp: int, device_key: str, samples: Sequence[ProbeSample],
              size_of: Callable[[int], dict[str, float]], units: dict[str, str], *,
              rounds: int = 1, order: Sequence[str] = (),
              max_spread: float = DEFAULT_MAX_SPREAD) -> CostModel:
    """Fit every stage of ``samples`` (wall and, where measured, kernel time) against
    its size; flag probes whose rounds spread more than ``max_spread`` of their median."""
    names = sorted({name for s in samples for name in s.wall_s})
    stages = {}
    for name in names:
        sizes = [s.sizes.get(name, 0.0) for s in samples]
        wall = fit_line(sizes, [s.wall_s.get(name, 0.0) for s in samples])
        kernel = (None if any(s.kernel_s is None for s in samples) else
                  fit_line(sizes, [(s.kernel_s or {}).get(name, 0.0) for s in samples]))
        harness = (None if any(s.harness_s is None for s in samples) else
                   fit_line(sizes, [(s.harness_s or {}).get(name, 0.0) for s in samples]))
        stages[name] = StageModel(name, units.get(name, PIXEL_UNIT), wall, kernel, harness)
    flags = []
    by_probe: dict[Probe, list[float]] = {}
    for s in samples:
        by_probe.setdefault(s.probe, []).append(s.frame_s)
    for probe, values in by_probe.items():
        middle = median_low(values)
        if len(values) > 1 and middle > 0 and (max(values) - min(values)) / middle > max_spread:
            flags.append(f"probe {probe.label()}: its rounds spread "
                         f"{100 * (max(values) - min(values)) / middle:.0f} % of their median "
                         f"(bound {100 * max_spread:.0f} %): the machine's speed drifted")
    load = merge_loads([s.load for s in samples])
    if load and load["loaded"]:
        flags.append("machine loaded during the probes: " + "; ".join(load["reasons"]))
    return CostModel(method, spp, device_key, stages, list(samples), rounds, list(order),
                     flags, load, size_of)


class SceneSlot:
    """One loaded scene at a time, by key (e.g. a resolution): asking for another key
    drops the one held first. A frame's host time grows with the shapes, emitters and
    BSDFs alive anywhere in the process (Dr.Jit traces a symbolic call for every
    registered instance of its class): with the many-lights scene loaded beside door,
    a pt frame of door at 8x8 took 14.9 ms instead of 4.5 ms, its kernels unchanged
    (docs/timing.md). Probes must not pay for scenes they do not render."""

    def __init__(self, load: Callable[[Any], Any]) -> None:
        self.load = load
        self.key: Any = None
        self.scene: Any = None

    def __call__(self, key: Any) -> Any:
        if self.scene is None or key != self.key:
            self.scene = None
            gc.collect()
            self.key, self.scene = key, self.load(key)
        return self.scene


#: Renders ``frames`` frames of a method configuration at a square resolution with the
#: given parameters; returns its timings (renderers.timing.summarize).
ProbeRender = Callable[[int, Any, int], dict[str, Any]]


def probes_for(method: Any, resolutions: Sequence[int],
               floor_factors: Sequence[float]) -> list[Probe]:
    """Every resolution at floors x1, and for a method with floors the smallest
    resolution at every other factor (what makes the floored stages' sizes vary)."""
    probes = [Probe(r) for r in sorted(set(resolutions))]
    if method.scale_floors is not None:
        probes += [Probe(min(resolutions), f) for f in sorted(set(floor_factors)) if f != 1]
    return probes


def measure(method: Any, params: Any, spp: int, device_key: str, render: ProbeRender, *,
            resolutions: Sequence[int] = DEFAULT_RESOLUTIONS,
            floor_factors: Sequence[float] = DEFAULT_FLOOR_FACTORS,
            rounds: int = DEFAULT_ROUNDS,
            progress: Callable[[int, int], None] | None = None) -> CostModel:
    """Time ``method`` with ``params`` at every probe (:func:`probes_for`) in
    ``rounds`` interleaved rounds with ``render`` and fit its cost model."""
    if len(set(resolutions)) < 2:
        raise ValueError("the cost model needs at least two resolutions")
    probes = probes_for(method, resolutions, floor_factors)
    done, total = 0, rounds * len(probes)

    def stage_sizes(probe_params: Any, pixels: int, names: set[str]) -> dict[str, float]:
        """Each stage's size: the method's rule, else pixels x spp."""
        declared = method.stage_sizes(probe_params, pixels, spp)
        return {name: float(declared.get(name, pixels * spp)) for name in names}

    def timed(probe: Probe) -> ProbeSample:
        nonlocal done
        probe_params = (params if probe.floor_factor == 1 else
                        method.scale_floors(params, probe.floor_factor))
        timings = render(probe.resolution, probe_params, spp)
        frames = [FrameTime.from_json(f) for f in timings["frames_detail"]]
        names = {name for f in frames for name in f.parts()}
        done += 1
        if progress:
            progress(done, total)
        return sample_of(probe, frames, stage_sizes(probe_params, probe.resolution ** 2, names),
                         timings.get("load"))

    timed_rounds = interleaved_rounds(probes, timed, rounds, name=lambda p: p.label())
    samples = [s for values in timed_rounds.times.values() for s in values]
    declared = set(method.stage_sizes(params, 1, spp))
    units = {name: ("units per frame (the method's own rule)" if name in declared
                    else PIXEL_UNIT) for name in {n for s in samples for n in s.wall_s}}

    def size_of(pixels: int) -> dict[str, float]:
        return stage_sizes(params, pixels, set(units))

    return fit_model(method.name, spp, device_key, samples, size_of, units, rounds=rounds,
                     order=timed_rounds.order)
