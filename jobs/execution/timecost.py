"""How long a job will take on this device, estimated before it runs.

A job's work (jobs/execution/work.py) counts, per part, its path samples, its frames
(or reference passes) and its renders. Its time is estimated as

    seconds = sum over parts of  renders x start_s + frames x frame_s + samples x sample_s

with the three costs measured on this device: from the stored runs of the same
method on the same scene and device key (``seconds_per_frame`` against path
samples per frame for ``frame_s`` and ``sample_s``, ``warmup_s`` for ``start_s``),
and for the reference from the stored references of that scene (render seconds per
pass against samples per pass). Where nothing is measured, :data:`DEFAULT` holds
(conservative: a slow CPU's costs, so an unmeasured job is over-, not under-
estimated). A sweep's parts use the slowest of its methods.

Fitting: with frames of at least two sizes (2x apart), a least-squares line through
(samples per frame, seconds per frame), moved up until no measured frame lies above
it; with one size, the measured frame time covers every smaller frame and larger
ones add the default cost per extra sample.

The service refuses a job estimated above ``Settings.max_job_seconds`` (422 with
the estimate by part) and gives an attempt without ``--job-timeout`` a timeout of
at least twice its estimate. Everything here goes through :func:`estimate_seconds`,
so that a finer cost model (per stage of a frame) can replace it in one place.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass, field

from sqlalchemy import select

from jobs.execution.work import WorkEstimate
from jobs.record.models import Reference, Run
from jobs.record.store import Store
from renderers.backend import cpu_device_key

#: Stored runs (newest first) or references read per (method, scene, device).
MAX_SAMPLES_READ = 50
#: An attempt's timeout is at least this many times its estimated time.
TIMEOUT_OVER_ESTIMATE = 2.0


@dataclass(frozen=True)
class Costs:
    """Seconds a render costs on a device: to start, per frame, per path sample."""

    start_s: float
    frame_s: float
    sample_s: float
    source: str

    def seconds(self, renders: int, frames: int, samples: int) -> float:
        return renders * self.start_s + frames * self.frame_s + samples * self.sample_s


#: Costs where nothing was measured: a render's start-up (scene, JIT) 1 s, a frame
#: 50 ms (a cache method's training step; a reference pass at 8x8 costs ~45 ms), a
#: path sample 1 us (1e6 samples/s, slower than this 2-core CPU's PT).
DEFAULT = Costs(start_s=1.0, frame_s=0.05, sample_s=1e-6, source="default (nothing measured)")


@dataclass
class TimeEstimate:
    """A job's estimated seconds, by part, and where each part's costs came from."""

    seconds: float = 0.0
    parts: dict[str, float] = field(default_factory=dict)
    sources: dict[str, str] = field(default_factory=dict)

    def describe(self) -> str:
        return ", ".join(f"{part} {seconds:.0f} s" for part, seconds in self.parts.items())


def device_key_of(device_class: str) -> str:
    """The device key (as stored with runs) whose measurements estimate a job of
    ``device_class``: this machine's CPU; for GPU jobs, any GPU's (prefix 'cuda:')."""
    return cpu_device_key() if device_class == "cpu" else "cuda:"


def _matches(key: str, device: str) -> bool:
    return key.startswith(device) if device.endswith(":") else key == device


def fit(points: list[tuple[float, float]], starts: list[float], source: str) -> Costs:
    """Costs from measured (samples per frame, seconds per frame) and start-up times."""
    start_s = statistics.median(starts) if starts else DEFAULT.start_s
    sizes = [n for n, _ in points]
    if len(points) >= 2 and max(sizes) >= 2 * min(sizes):
        mean_n, mean_t = statistics.fmean(sizes), statistics.fmean(t for _, t in points)
        spread = sum((n - mean_n) ** 2 for n in sizes)
        sample_s = max(0.0, sum((n - mean_n) * (t - mean_t) for n, t in points) / spread)
        frame_s = max(0.0, mean_t - sample_s * mean_n)
        # Up until no measured frame is slower than the line says.
        frame_s += max(0.0, max(t - (frame_s + sample_s * n) for n, t in points))
        return Costs(start_s, frame_s, sample_s, source)
    size, frame = max(points)   # one size: its frame time covers every smaller frame
    return _OneSize(start_s, frame, DEFAULT.sample_s, source, size)


@dataclass(frozen=True)
class _OneSize(Costs):
    """Frames measured at one size only: ``frame_s`` is that frame's time, and a larger
    frame adds the default cost per extra sample."""

    size: float = 0.0

    def seconds(self, renders: int, frames: int, samples: int) -> float:
        per_frame = samples / frames if frames else 0.0
        extra = max(0.0, per_frame - self.size) * frames
        return renders * self.start_s + frames * self.frame_s + extra * self.sample_s


def method_costs(store: Store, method: str, scene: str, device: str) -> Costs:
    """Costs of ``method`` on ``scene`` from its stored runs on ``device``."""
    with store.session() as session:
        rows = session.execute(
            select(Run.device_key, Run.width, Run.height, Run.spp, Run.timings)
            .where(Run.method == method, Run.scene_name == scene, Run.status == "succeeded")
            .order_by(Run.id.desc()).limit(4 * MAX_SAMPLES_READ)).all()
    points, starts = [], []
    for key, width, height, spp, timings in rows:
        frame = (timings or {}).get("seconds_per_frame")
        if not _matches(key, device) or not isinstance(frame, int | float) or frame <= 0:
            continue
        points.append((float(width * height * spp), float(frame)))
        if isinstance(timings.get("warmup_s"), int | float):
            starts.append(float(timings["warmup_s"]))
        if len(points) >= MAX_SAMPLES_READ:
            break
    if not points:
        return DEFAULT
    return fit(points, starts, f"{len(points)} stored runs of {method} on this device")


def reference_costs(store: Store, scene: str, device: str) -> Costs:
    """Costs of a reference pass of ``scene`` from its stored references on ``device``."""
    with store.session() as session:
        rows = session.execute(
            select(Reference.width, Reference.height, Reference.spp, Reference.passes,
                   Reference.render_seconds, Reference.device)
            .where(Reference.scene_name == scene).order_by(Reference.id.desc())
            .limit(4 * MAX_SAMPLES_READ)).all()
    points = [(width * height * spp / passes, seconds / passes)
              for width, height, spp, passes, seconds, info in rows
              if passes and seconds and _matches(str((info or {}).get("device_key", "")), device)]
    if not points:
        return DEFAULT
    return fit(points[:MAX_SAMPLES_READ], [], f"{len(points)} stored references on this device")


def estimate_seconds(work: WorkEstimate, methods: list[str], scene: str, store: Store,
                     device_class: str = "cpu") -> TimeEstimate:
    """The time of ``work``: the reference part at the scene's reference costs, every
    other part at the slowest of ``methods``' costs."""
    device = device_key_of(device_class)
    slowest = max((method_costs(store, method, scene, device) for method in methods),
                  key=lambda costs: costs.seconds(1, 10, 10 * 65536))
    estimate = TimeEstimate()
    reference: Costs | None = None
    for part, samples in work.parts.items():
        if part == "reference":
            reference = reference or reference_costs(store, scene, device)
            costs = reference
        else:
            costs = slowest
        seconds = costs.seconds(work.renders.get(part, 0), work.frames.get(part, 0), samples)
        estimate.parts[part] = estimate.parts.get(part, 0.0) + seconds
        estimate.sources[part] = costs.source
        estimate.seconds += seconds
    return estimate
