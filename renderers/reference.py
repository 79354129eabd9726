"""Converged reference images: progressive passes with a per-pixel variance.

A reference is rendered in passes of ``spp_per_pass`` samples, each pass with
its own derived seed, so pass means are independent and identically
distributed. Their running mean is the reference; the sample variance of the
pass means divided by the number of passes is the per-pixel variance *of the
reference* (what the z-tests and the error floor need). Rendering stops at the
target spp, or earlier once the relative standard error falls below the
target (after a minimum number of passes, so the variance estimate is usable).

The even and odd passes also form two independent half references: their
difference measures the reference's own residual error, the floor under every
metric computed against it.

By default references use Mitsuba's built-in ``path`` integrator, independent of
the code under test (our ``pt`` is tested for agreement with it).

Mean and variance are accumulated in float64 and kept as float32, the precision
they are stored in (EXR). A value beyond float32's range (about 3.4e38; where an
emitter of radiance 1e30 lights a pixel, the variance of its mean is 1e51 to
1e57) is kept as an infinity of its sign, on purpose and without a cast that
overflows: its readers take it as "overflowed" (the run's quality verdict says
so, the error metrics leave the pixel out, the stress suite's agreement cannot
test it), where a finite clamp at the float32 maximum would understate it by up
to ~19 orders of magnitude and let the metrics compute on it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np

from metrics.errors import mrse
from metrics.statistics import PassAccumulator
from renderers.seeding import derive_seed
from renderers.timing import synchronize

REFERENCE_INTEGRATORS = ("path", "pt")


@dataclass(frozen=True)
class ReferenceSettings:
    """Everything that determines a reference besides the scene and resolution."""

    integrator: str = "path"         # 'path' (Mitsuba built-in) or 'pt' (our core)
    max_depth: int = -1              # -1: unbounded (roulette), as renders and training paths
    spp: int = 4096                  # target (and maximum) samples per pixel
    spp_per_pass: int = 64
    rel_stderr: float | None = None  # stop early below this relative standard error
    min_passes: int = 8

    def validate(self) -> None:
        if self.integrator not in REFERENCE_INTEGRATORS:
            raise ValueError(f"reference integrator must be one of {REFERENCE_INTEGRATORS}")
        if self.max_depth == 0 or self.max_depth < -1:
            raise ValueError("max_depth must be -1 (unbounded) or >= 1")
        if not 1 <= self.spp_per_pass <= 1 << 16:
            raise ValueError("spp_per_pass must be in 1..65536")
        if not self.min_passes <= self.spp <= 1 << 24:
            raise ValueError(f"reference spp must be in {self.min_passes}..16777216")
        if self.rel_stderr is not None and not self.rel_stderr > 0:
            raise ValueError("target relative standard error must be > 0")
        if self.min_passes < 2:
            raise ValueError("min_passes must be >= 2 (a variance needs two passes)")

    def pass_spp(self) -> int:
        """Samples per pass, reduced so that at least ``min_passes`` passes run."""
        return max(1, min(self.spp_per_pass, self.spp // self.min_passes))

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def as_float32(values: np.ndarray) -> np.ndarray:
    """``values`` as float32, a magnitude beyond its range as an infinity of its sign
    (module docstring)."""
    limit = float(np.finfo(np.float32).max)
    return np.where(np.abs(values) > limit, np.copysign(np.inf, values),
                    values).astype(np.float32)


@dataclass
class ReferenceImage:
    mean: np.ndarray               # (H, W, 3) float32
    variance: np.ndarray           # (H, W, 3) float32, variance of ``mean`` per pixel;
                                   # +inf where it exceeds float32 (module docstring)
    spp: int
    passes: int
    rel_stderr: float
    split_half: dict[str, float]   # half-vs-half error: the floor under every metric
    seconds: float


def reference_integrator(settings: ReferenceSettings) -> Any:
    import mitsuba as mi

    if settings.integrator == "path":
        return mi.load_dict({"type": "path", "max_depth": settings.max_depth})
    from renderers.methods.pt import PTParams, path_integrator

    return path_integrator(PTParams(max_depth=settings.max_depth))


def split_half_floor(acc: PassAccumulator) -> dict[str, float]:
    """MRSE between the two half references, and what it implies for the full one.

    For independent halves A, B with equal variance v per pixel, E(A-B)^2 = 2v
    and the full reference (A+B)/2 has variance v/2: its own expected MRSE is a
    quarter of the half-vs-half MRSE.
    """
    half_a, half_b = acc.split_halves()
    half_mrse = mrse(half_a, half_b)
    return {"half_vs_half_mrse": half_mrse, "reference_mrse_estimate": half_mrse / 4.0}


class PassSink(Protocol):
    """Where :func:`render_passes` puts each pass image (a PassAccumulator, RunningMoments)."""

    def add(self, image: np.ndarray) -> None: ...


def render_passes(scene: Any, integrator: Any, *, pass_spp: int, passes: int,
                  seed_of: Callable[[int], int], sink: PassSink,
                  progress: Callable[[int, int], None] | None = None,
                  enough: Callable[[], bool] = lambda: False) -> float:
    """Render up to ``passes`` independent passes of ``pass_spp`` samples (pass i with seed
    ``seed_of(i)``) into ``sink`` (RGB, float64), stopping early once ``enough()``.
    Returns the seconds spent. The references and the cache-at-v1 images use it."""
    import mitsuba as mi

    start = time.perf_counter()
    for index in range(passes):
        image = mi.render(scene, integrator=integrator, spp=pass_spp, seed=seed_of(index))
        synchronize(image)
        sink.add(np.asarray(image)[..., :3].astype(np.float64))
        if progress:
            progress((index + 1) * pass_spp, passes * pass_spp)
        if enough():
            break
    return time.perf_counter() - start


def render_reference(
    scene: Any,
    settings: ReferenceSettings,
    *,
    seed_parts: tuple[Any, ...],
    progress: Callable[[int, int], None] | None = None,
) -> ReferenceImage:
    """Render passes until the stopping rule holds (see module docstring)."""
    settings.validate()
    acc = PassAccumulator()
    pass_spp = settings.pass_spp()
    seconds = render_passes(
        scene, reference_integrator(settings), pass_spp=pass_spp,
        passes=settings.spp // pass_spp, sink=acc, progress=progress,
        seed_of=lambda index: derive_seed(*seed_parts, "reference-pass", index),
        enough=lambda: (settings.rel_stderr is not None and acc.count >= settings.min_passes
                        and acc.relative_stderr() <= settings.rel_stderr))
    return ReferenceImage(
        mean=as_float32(acc.mean),
        variance=as_float32(acc.variance_of_mean),
        spp=acc.count * pass_spp,
        passes=acc.count,
        rel_stderr=float(acc.relative_stderr()),
        split_half=split_half_floor(acc),
        seconds=seconds,
    )
