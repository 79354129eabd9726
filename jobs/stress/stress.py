"""The numerical-stability stress suite (``nirc-bench stress``, docs/stress.md).

Adversarial scenes (:mod:`jobs.stress.stress_scenes`) run through every
registered method as ordinary render jobs, embedded or on a service, and each
(case, method) is reduced to one :class:`StressRow`: did it run (or why not),
how many non-finite pixels, training losses, skipped steps and cache weights
it produced, the largest pixel value, whether an unbiased method still agrees
with the reference, whether any non-finite value reached a stored metric, how
many points its plotted series lack, and what the user was told (the quality
verdict, its reasons and warnings).

Non-finite values are counted on the values themselves, never after a JSON
conversion (which turns NaN into null, the same as a metric the verdict
withholds): the executor stores a NaN or infinite metric, statistic or loss as
null and names it in the run's ``quality['nonfinite_values']`` (what a run on a
service reports), and the embedded backend hands over the stored run unconverted,
so a number that escaped that is counted as well.

A method whose parameters have an ``estimator`` choice runs once per choice
(``nirc`` biased and unbiased). Which runs are unbiased, and so tested for
agreement, is what the method declares: an ``estimator`` parameter of
``'unbiased'``, or ``Method.unbiased``; a method that declares neither is not
tested.

Agreement is :func:`metrics.statistics.agreement_test` (per-pixel Šidák test
and the aggregate block test, each at :func:`agreement_level`: the suite's exit
status has the family-wise level alpha, 0.01, over every agreement it may require)
of the K seeds' mean, with the variance of that mean estimated from the seeds
(K - 1 degrees of freedom) and floored at half the reference integrator's at the
seeds' sample count (:func:`floored_variance`), against the reference (its
per-pixel variance of the mean), or, when the reference's pixels are not at hand
(a run on a service), against the K seeds of the baseline method of the same case. A method whose pixels share samples
(``Method.correlated_pixels``: spatial reuse) takes the image-mean test
(:func:`metrics.statistics.image_mean_test`) in place of the block test, which
assumes independent pixels.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol, get_args, get_origin

import numpy as np
from pydantic import BaseModel, Field

from jobs.protocol.spec import ReferenceSpec, RenderSpec
from jobs.stress import stress_scenes as scenes
from jobs.views.plots import dropped_points
from metrics.statistics import AgreementResult, agreement_test, image_mean_test, z_test
from renderers.methods import BASELINE, METHODS, Method, NotApplicable, check_applies
from renderers.scenes import SceneError


@dataclass(frozen=True)
class StressCase:
    """One adversarial scene: what it stresses and whether unbiased methods must agree
    with the reference on it at the suite's sample counts."""

    name: str
    checks: str
    build: Callable[[], scenes.StressScene]
    agree: bool = True


CASES: tuple[StressCase, ...] = (
    StressCase("fireflies", "a tiny light 1e6 times brighter than the room's: rare, huge "
               "path contributions", scenes.fireflies, agree=False),
    StressCase("near-black", "black walls: a reference ~0 almost everywhere (relative metrics)",
               scenes.near_black),
    # Near-delta lobes give heavy-tailed pixels: with a few seeds the aggregate test
    # rejected pt-spatial, which with one emitter samples exactly as pt (docs/stress.md).
    StressCase("near-mirror", "roughness 1e-4 (conductor walls, plastic box): near-delta lobes",
               scenes.near_mirror, agree=False),
    StressCase("grazing", "a floor seen and lit at grazing angles (cosines ~0)",
               scenes.grazing),
    StressCase("envmap-1e5", "an environment map with a 1e5 dynamic range (one small sun)",
               scenes.environment, agree=False),
    StressCase("degenerate-triangles", "zero-area triangles (collinear, repeated vertices)",
               scenes.degenerate_triangles),
    StressCase("radiance-1e30", "a second emitter of radiance 1e30 (variances overflow float32)",
               scenes.radiance("1e30, 1e30, 1e30"), agree=False),
    StressCase("radiance-0", "a second emitter of radiance 0 (zero power for power-based "
               "light selection)",
               scenes.radiance("0, 0, 0")),
    StressCase("radiance-inf", "an emitter of infinite radiance (refused at load)",
               scenes.radiance("inf, inf, inf")),
    StressCase("no-emitter", "no emitter at all: every pixel 0", scenes.no_emitter),
    StressCase("scale-1e6", "the room scaled by 1e6", lambda: scenes.room(scale=1e6)),
    StressCase("scale-1e-6", "the room scaled by 1e-6", lambda: scenes.room(scale=1e-6)),
    StressCase("closed-box", "the camera inside a closed box lit by a point light",
               scenes.closed_box),
)


def get_cases(names: Iterable[str] | None = None) -> list[StressCase]:
    """The cases named (all by default); an unknown name is a SceneError naming them."""
    by_name = {case.name: case for case in CASES}
    if names is None:
        return list(CASES)
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise SceneError(f"unknown stress case(s) {', '.join(unknown)}; "
                         f"available: {', '.join(by_name)}")
    return [by_name[n] for n in names]


@dataclass(frozen=True)
class Variant:
    """A method with parameters: one row of every case."""

    method: str
    params: dict[str, Any]
    unbiased: bool
    correlated_pixels: bool = False

    @property
    def label(self) -> str:
        extra = ",".join(f"{k}={v}" for k, v in self.params.items())
        return f"{self.method} ({extra})" if extra else self.method


def _estimators(method: Method) -> tuple[str, ...]:
    field = method.params.model_fields.get("estimator")
    if field is None or get_origin(field.annotation) is not Literal:
        return ()
    return tuple(str(v) for v in get_args(field.annotation))


def variants() -> list[Variant]:
    """Every registered method, once per ``estimator`` choice (module docstring)."""
    rows = []
    for name, method in METHODS.items():
        choices = _estimators(method)
        correlated = method.correlated_pixels
        if not choices:
            rows.append(Variant(name, {}, unbiased=method.unbiased is True,
                                correlated_pixels=correlated))
        for choice in choices:
            rows.append(Variant(name, {"estimator": choice}, unbiased=choice == "unbiased",
                                correlated_pixels=correlated))
    return rows


class StressSettings(BaseModel):
    """Sizes of the suite's renders."""

    resolution: int = Field(16, ge=4, le=512)
    spp: int = Field(4, ge=1, le=1024)
    frames: int = Field(2, ge=1, le=64)
    seeds: int = Field(8, ge=2, le=64, description="K >= 2: agreement needs a variance")
    reference_spp: int = Field(1024, ge=8, le=1 << 20)
    alpha: float = Field(0.01, gt=0.0, lt=1.0,
                         description="family-wise level of the agreements the suite requires "
                                     "(agreement_level)")

    def samples_ratio(self, against: str) -> float:
        """Samples behind the mean unbiased runs are tested against ('reference': the
        reference's spp; 'baseline': the baseline's K seeds, as many as the run's) per
        sample behind a run's mean of its K seeds (spp x frames each)."""
        if against == "baseline":
            return 1.0
        return self.reference_spp / (self.spp * self.frames * self.seeds)

    def spec(self, scene: str, variant: Variant) -> RenderSpec:
        return RenderSpec(scene=scene, method=variant.method, params=variant.params,
                          resolution=self.resolution, spp=self.spp, frames=self.frames,
                          seeds=self.seeds, reference=ReferenceSpec(spp=self.reference_spp))


@dataclass
class Outcome:
    """What a backend returns for one finished render job."""

    detail: dict[str, Any]                               # RunResultDetail JSON
    images: list[np.ndarray]                             # the K seeds' images
    reference: tuple[np.ndarray, np.ndarray] | None      # (mean, variance of the mean)


class Refused(Exception):
    """The scene was refused; the message is what the user was told."""


class Backend(Protocol):
    """Where the jobs run: here (embedded) or on a service."""

    #: What the agreement is tested against: 'reference' or 'baseline'.
    against: str

    def scene(self, path: Path) -> str:
        """The scene name a job spec gives for the XML at ``path`` (raise Refused)."""

    def run(self, spec: RenderSpec) -> Outcome:
        """Run ``spec`` to completion (raise Refused for a refused scene)."""


class StressRow(BaseModel):
    """One (case, method) of the stress table."""

    case: str
    method: str
    status: Literal["ok", "skipped", "refused", "error"]
    message: str = ""
    nonfinite_pixels: int | None = None
    nonfinite_losses: int | None = None          # recorded losses that are NaN/Inf
    skipped_steps: int | None = None             # training steps skipped (non-finite)
    dropped_records: int | None = None           # training records dropped (non-finite)
    nonfinite_weights: int | None = None         # in the caches' final weights
    nonfinite_metrics: int | None = None         # metric values that came out NaN/Inf
    dropped_plot_points: int | None = None       # missing or non-finite points of its plots
    max_pixel: float | None = None               # largest finite pixel value
    agreement: str | None = None                 # 'agrees' / 'DIFFERS' / None: not tested
    agreement_detail: str = ""
    expected_agreement: bool = False
    verdict: str | None = None
    told: list[str] = Field(default_factory=list)  # verdict reasons and warnings
    seconds: float = 0.0


class StressReport(BaseModel):
    settings: StressSettings
    against: str
    rows: list[StressRow]

    def problems(self) -> list[str]:
        """What the suite exists to catch: a crash, a non-finite value in a metric, a
        training loss or a stored weight, or an unbiased method that no longer agrees
        where it must."""
        found = []
        for row in self.rows:
            where = f"{row.case} / {row.method}"
            if row.status == "error":
                found.append(f"{where}: {row.message}")
            if row.nonfinite_metrics:
                found.append(f"{where}: {row.nonfinite_metrics} non-finite metric values")
            if row.nonfinite_losses:
                found.append(f"{where}: {row.nonfinite_losses} non-finite training losses")
            if row.nonfinite_weights:
                found.append(f"{where}: {row.nonfinite_weights} non-finite cache weights")
            if row.expected_agreement and row.agreement == "DIFFERS":
                found.append(f"{where}: unbiased but differs ({row.agreement_detail})")
        return found


def agreement_level(alpha: float) -> float:
    """The level of each agreement test, so that correct methods fail the suite with
    probability at most ``alpha``: Bonferroni over the two tests (per-pixel and
    aggregate) of every pair of a case that requires agreement and an unbiased variant
    of the registry, as ``nirc-bench ci`` splits its level over its rows. The pairs are
    counted whether or not this invocation runs them, so a row's verdict does not
    depend on ``--case``. At alpha per test the ~40 rows the suite tests would fail a
    suite of correct methods about every second run (docs/stress.md)."""
    return alpha / (2 * max(1, required_pairs()))


def required_pairs() -> int:
    """Pairs of a case that requires agreement and an unbiased variant of the registry."""
    return sum(case.agree for case in CASES) * sum(v.unbiased for v in variants())


# ---------------------------------------------------------------------------
# Reducing one finished job to a row
# ---------------------------------------------------------------------------


def count_nonfinite_values(value: Any) -> int:
    """NaN or infinite numbers anywhere in a JSON-like ``value``."""
    if isinstance(value, float):
        return 0 if math.isfinite(value) else 1
    if isinstance(value, dict):
        return sum(count_nonfinite_values(v) for v in value.values())
    if isinstance(value, list | tuple):
        return sum(count_nonfinite_values(v) for v in value)
    return 0


def training_counts(method_stats: Iterable[dict[str, Any] | None]) -> dict[str, int | None]:
    """Non-finite losses, skipped steps, dropped records and non-finite weights summed
    over the seeds' caches (all None for a method without a cache)."""
    caches = [s for s in method_stats if s and "cache_stats" in s]
    if not caches:
        return dict.fromkeys(("nonfinite_losses", "skipped_steps", "dropped_records",
                              "nonfinite_weights"))
    stats = [s["cache_stats"] for s in caches]
    return {
        "nonfinite_losses": sum(count_nonfinite_values(losses) for s in caches
                                for losses in loss_histories(s)),
        "skipped_steps": sum(int(c.get("skipped_steps", 0)) for c in stats),
        "dropped_records": sum(int(c.get("dropped_nonfinite_targets", 0))
                               + int(c.get("dropped_nonfinite_inputs", 0)) for c in stats),
        "nonfinite_weights": sum(int(c.get("nonfinite_weights", 0)) for c in stats),
    }


def loss_histories(method_stats: dict[str, Any]) -> list[list[Any]]:
    """Every loss curve of a seed's method statistics (``loss_history``, and a second
    cache's under its own key, e.g. ``env_cache``)."""
    curves = [method_stats.get("loss_history") or []]
    curves += [v["loss_history"] for v in method_stats.values()
               if isinstance(v, dict) and "loss_history" in v]
    return curves


def stored_nonfinite(quality: dict[str, Any]) -> tuple[int, int]:
    """(metrics, losses): the NaN or infinite values the executor stored as null
    (``quality['nonfinite_values']``, paths such as ``seed 0.method_stats.loss_history[3]``)."""
    paths = quality.get("nonfinite_values") or []
    losses = sum(1 for path in paths if "loss_history" in path)
    return len(paths) - losses, losses


def convergence_drops(per_seed: Iterable[dict[str, Any]]) -> int:
    """Points the error-over-frames plot (the executor's ``convergence.png``) leaves out
    of the seeds' curves as missing or not finite."""
    return sum(dropped_points(curve)
               for s in per_seed
               for curve in ((s["metrics"].get("convergence") or {}).values()))


def seed_moments(images: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Mean of the K seeds' images and the variance of that mean, (K-1)-dof estimate."""
    stack = np.stack([np.asarray(i, dtype=np.float64)[..., :3] for i in images])
    with np.errstate(invalid="ignore", over="ignore"):
        return stack.mean(axis=0), stack.var(axis=0, ddof=1) / len(images)


#: The floor of the seeds' variance of their mean, as a fraction of the reference
#: integrator's at the seeds' sample count (:func:`floored_variance`).
VARIANCE_FLOOR = 0.5


def floored_variance(variance: np.ndarray, other_variance: np.ndarray,
                     samples_ratio: float) -> np.ndarray:
    """The seeds' variance of their mean, at least VARIANCE_FLOOR times ``other``'s
    variance of its mean times ``samples_ratio`` (the samples behind ``other``'s mean
    per sample behind the seeds'), i.e. half the reference integrator's variance at the
    seeds' sample count.

    K seeds estimate a pixel's variance badly where few of its samples are not 0 (a
    shape covering a few percent of the pixel): all K spp frames samples are 0 with
    probability (1 - c)^(K spp frames), the estimate is then 0 while the reference's
    mean is not, and a tile's z is the difference over the reference's noise alone.
    The CI's stress run (8 x 8, 2 spp x 2 frames, K = 4, 256-spp reference) rejected
    such correct renders on ``near-black`` (docs/stress.md): of 128 groups of 4 seeds
    at 5e-5 per test, 3 of `pt` and 4 of `cv-sh`; with the floor none. The floor only
    raises variances, so the test keeps its level; it binds where the estimate falls
    below half the reference integrator's (for K = 4 normal pixels a third of them),
    which costs a little power, and more for a method whose variance is below half the
    reference integrator's."""
    with np.errstate(invalid="ignore", over="ignore"):
        return np.maximum(variance, VARIANCE_FLOOR * samples_ratio * other_variance)


def agreement(images: list[np.ndarray], other: tuple[np.ndarray, np.ndarray],
              alpha: float, correlated_pixels: bool = False, *,
              samples_ratio: float) -> tuple[str, str]:
    """('agrees' or 'DIFFERS', the tests' summary) of the seeds against ``other``, the
    seeds' variance floored (:func:`floored_variance`; ``samples_ratio``: the samples
    behind ``other``'s mean per sample behind the seeds' mean). Pixels that share
    samples (``correlated_pixels``) take the image-mean test in place of the tile test,
    which assumes independent pixels."""
    mean, variance = seed_moments(images)
    ref_mean, ref_var = other[0][..., :3], other[1][..., :3]
    variance = floored_variance(variance, ref_var, samples_ratio)
    if correlated_pixels:
        result = AgreementResult(
            z_test(mean, variance, ref_mean, ref_var, alpha=alpha, dof=len(images) - 1),
            image_mean_test(np.stack([i[..., :3] for i in images]), ref_mean, ref_var, alpha))
    else:
        result = agreement_test(mean, variance, ref_mean, ref_var, dof=len(images) - 1,
                                alpha=alpha)
    return ("agrees" if result.passed else "DIFFERS"), result.summary()


def row_of(case: StressCase, variant: Variant, outcome: Outcome,
           against: tuple[np.ndarray, np.ndarray] | None, alpha: float,
           samples_ratio: float) -> StressRow:
    """The row of a finished job (``against``: what unbiased runs are tested against;
    ``samples_ratio``: :func:`agreement`'s)."""
    detail = outcome.detail
    quality = detail.get("quality") or {}
    per_seed = detail.get("per_seed", [])
    stats = [s["metrics"].get("method_stats") for s in per_seed]
    finite = [i[np.isfinite(i)] for i in outcome.images]
    told = [r["message"] for r in quality.get("reasons", [])] + list(detail.get("warnings") or [])
    stored_metrics, stored_losses = stored_nonfinite(quality)
    counts = training_counts(stats)
    if stored_losses:
        counts["nonfinite_losses"] = (counts["nonfinite_losses"] or 0) + stored_losses
    row = StressRow(
        case=case.name, method=variant.label, status="ok",
        nonfinite_pixels=int(quality.get("nonfinite_pixels", 0)),
        nonfinite_metrics=stored_metrics + count_nonfinite_values(detail.get("metrics"))
        + sum(count_nonfinite_values({k: v for k, v in s["metrics"].items()
                                      if k != "method_stats"}) for s in per_seed),
        dropped_plot_points=convergence_drops(per_seed),
        max_pixel=max((float(f.max()) for f in finite if f.size), default=None),
        verdict=quality.get("verdict"), told=told, **counts)
    if variant.unbiased and against is not None and len(outcome.images) >= 2:
        row.expected_agreement = case.agree
        row.agreement, row.agreement_detail = agreement(
            outcome.images, against, alpha, variant.correlated_pixels,
            samples_ratio=samples_ratio)
    return row


# ---------------------------------------------------------------------------
# The suite
# ---------------------------------------------------------------------------


def _features(path: Path, resolution: int) -> tuple[Any | None, str]:
    """The scene's features, or None and the message of its refusal."""
    from renderers.backend import init_backend
    from renderers.scenes import load_scene

    init_backend()
    try:
        return load_scene(str(path), resolution).features, ""
    except SceneError as err:
        return None, str(err)


def run_case(case: StressCase, backend: Backend, settings: StressSettings, folder: Path,
             progress: Callable[[str], None] | None = None) -> list[StressRow]:
    """Every variant on ``case``; see the module docstring."""
    path = case.build().write(folder / case.name)
    features, refusal = _features(path, settings.resolution)
    rows: list[StressRow] = []
    try:
        scene = backend.scene(path)
    except Refused as err:
        return [StressRow(case=case.name, method=v.label, status="refused", message=str(err))
                for v in variants()]
    baseline: tuple[np.ndarray, np.ndarray] | None = None
    # The baseline first: over a service its seeds are what the others are tested against.
    ordered = sorted(variants(), key=lambda v: v.method != BASELINE)
    for variant in ordered:
        if progress:
            progress(f"{case.name} / {variant.label}")
        start = time.perf_counter()
        if features is not None:
            try:
                check_applies(variant.method, features)
            except NotApplicable as err:
                rows.append(StressRow(case=case.name, method=variant.label, status="skipped",
                                      message=str(err).split(": ", 1)[-1]))
                continue
        try:
            outcome = backend.run(settings.spec(scene, variant))
        except Refused as err:
            rows.append(StressRow(case=case.name, method=variant.label, status="refused",
                                  message=str(err)))
            continue
        except Exception as err:  # noqa: BLE001 - a crash is what the suite reports
            status = "refused" if refusal else "error"
            rows.append(StressRow(case=case.name, method=variant.label, status=status,
                                  message=f"{type(err).__name__}: {err}"))
            continue
        if variant.method == BASELINE and not variant.params:
            baseline = seed_moments(outcome.images)
        against = outcome.reference if backend.against == "reference" else (
            None if variant.method == BASELINE else baseline)
        row = row_of(case, variant, outcome, against, agreement_level(settings.alpha),
                     settings.samples_ratio(backend.against))
        row.seconds = time.perf_counter() - start
        rows.append(row)
    order = {v.label: i for i, v in enumerate(variants())}
    return sorted(rows, key=lambda r: order[r.method])


def run_suite(backend: Backend, settings: StressSettings, cases: list[StressCase],
              progress: Callable[[str], None] | None = None) -> StressReport:
    with tempfile.TemporaryDirectory(prefix="nirc-stress-") as folder:
        rows = [row for case in cases
                for row in run_case(case, backend, settings, Path(folder), progress)]
    return StressReport(settings=settings, against=backend.against, rows=rows)


# ---------------------------------------------------------------------------
# Embedded backend and the table
# ---------------------------------------------------------------------------


class EmbeddedBackend:
    """Runs the jobs in this process through the executor, like ``nirc-bench render``."""

    against = "reference"

    def __init__(self, store: Any, settings: Any) -> None:
        self.store, self.settings = store, settings

    def scene(self, path: Path) -> str:
        return str(path)

    def run(self, spec: RenderSpec) -> Outcome:
        from jobs.protocol.executor import execute
        from jobs.protocol.job import RenderJob
        from jobs.protocol.references import stored_reference
        from jobs.views.export import export_run
        from metrics.imageio import read_exr

        with tempfile.TemporaryDirectory(prefix="nirc-stress-run-") as out:
            try:
                summary = execute(RenderJob.parse(spec), self.store, self.settings)
            except SceneError as err:
                raise Refused(str(err)) from None
            files = export_run(self.store.get_run(summary.run_id), summary.to_json(),
                               self.settings, Path(out))
            images = [read_exr(files[f"image_seed{k}.exr"]) for k in range(spec.seeds)]
        reference = stored_reference(self.store, self.settings.references_dir,
                                     summary.reference["id"])
        # Python values, not JSON: a NaN stays a NaN here (JSON would make it null).
        return Outcome(summary.result.model_dump(), images,
                       (reference.mean, reference.variance))


def _number(value: int | float | None) -> str:
    if value is None:
        return "–"
    return f"{value:.3g}" if isinstance(value, float) else str(value)


def markdown_table(report: StressReport) -> str:
    """The stress table (docs/stress.md shows one)."""
    lines = [f"| case | method | status | non-finite pixels | non-finite metrics / plot "
             "points dropped | non-finite losses / skipped steps / dropped records / weights "
             f"| max pixel | agreement (vs {report.against}) | verdict | told |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in report.rows:
        status = r.status if not r.message else f"{r.status}: {r.message}"
        training = ("–" if r.skipped_steps is None else
                    f"{r.nonfinite_losses} / {r.skipped_steps} / {r.dropped_records} / "
                    f"{r.nonfinite_weights}")
        agree = r.agreement or "–"
        if r.agreement and not r.expected_agreement:
            agree += " (not required)"
        told = "; ".join(r.told) or "–"
        values = ("–" if r.nonfinite_metrics is None else
                  f"{r.nonfinite_metrics} / {r.dropped_plot_points}")
        lines.append(f"| {r.case} | {r.method} | {status} | {_number(r.nonfinite_pixels)} | "
                     f"{values} | {training} | {_number(r.max_pixel)} | {agree} | "
                     f"{r.verdict or '–'} | {told} |".replace("\n", " "))
    return "\n".join(lines)
