"""The metric registry: one entry per metric, read by every place that stores or shows one.

The executor (per-seed and aggregated values), the API's result rows, the CLI
tables, the sweep's rows, table and figure, the Fig. 7 report and the dashboard
(``GET /api/v1/metrics``) are generated from :data:`METRICS`; the quality
verdict's withheld names (:mod:`metrics.quality`) are its ``verdict_name``.
Adding a metric is one :class:`Metric` in :data:`METRICS` plus its test
(docs/architecture.md, "Adding a metric").

How K seeds reduce to the stored value is the entry's :class:`Aggregate`.
Values that several metrics share one pass over the images for (MSE, MRSE,
FLIP with their finite-pixel masks and reference floor; MRSE's CI, rBias^2 and
rVar over the K renders) are computed by :func:`metrics.errors.image_metrics`
and :func:`metrics.errors.bias_variance`; their entries name the key they
store and give no ``per_seed`` function. A metric with its own per-image
function gives it as ``per_seed`` and is computed by :func:`per_seed_values`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Literal

import numpy as np

from metrics.bias_intervals import bias_verdict
from metrics.denoised import DENOISER_KEY
from metrics.errors import efficiency, psnr_tonemapped
from metrics.statistics import interval_or_reason


class Aggregate(StrEnum):
    """How the K seeds of a run reduce to the stored value."""

    #: mean over seeds of the per-seed values (seeds without a value left out)
    MEAN = "mean"
    #: mean over seeds with its 95 % interval under ``<seed_key>_ci95``, on the log scale
    #: so it stays above zero, none with K < 3 (metrics.errors.bias_variance,
    #: metrics.statistics.positive_mean_interval; the single value when K = 1)
    MEAN_CI = "mean_ci"
    #: from the K renders jointly, like rBias^2 and rVar (metrics.errors.bias_variance)
    BIAS_VARIANCE = "bias_variance"
    #: from each seed's own frames, mean over the caches (per_cache_bias_variance)
    PER_CACHE = "per_cache"
    #: from other aggregated values (``derive``), e.g. efficiency from MRSE and time
    DERIVED = "derived"


@dataclass(frozen=True)
class Metric:
    """One metric: what it is, how it is computed and reduced, where it is stored and shown."""

    name: str                      # registry name (unique)
    label: str                     # column / axis label
    description: str               # one line, for tooltips and docs
    direction: Literal["lower", "higher"]  # which way is better
    aggregate: Aggregate
    key: str                       # key of the aggregated value in a run's metrics
    seed_key: str | None = None    # key of the per-seed value in a seed's metrics
    per_seed: Callable[[np.ndarray, np.ndarray], float | None] | None = None  # (test, ref)
    derive: Callable[[Mapping[str, Any]], float | None] | None = None  # DERIVED only
    unit: str = ""
    log_axis: bool = False         # plotted on a log axis
    needs_k2: bool = False         # needs K >= 2 seeds (absent from a K = 1 run)
    group: str | None = None       # the quality verdict's name for it (default: ``name``)
    field: str | None = None       # name in result rows (API RunOut, sweep rows, report,
                                   # dashboard); None: shown in run details only
    sweep_plot: bool = False       # a panel of the sweep figure (NIRC paper Fig. 13)
    withheld_keys: tuple[str, ...] = ()  # further stored-key prefixes the verdict clears
    details: tuple[tuple[str, str], ...] = ()  # (label, stored key) shown beside it in details
    ci_min_change: float | None = None  # smallest relative change (worse way) nirc-bench ci
                                        # calls a regression; None: not gated (needs seed_key)
    interval: bool = False         # a BIAS_VARIANCE value stored with its 95 % interval
                                   # (``<key>_ci95``, metrics.bias_intervals)
    requires: str | None = None    # a key of a run's metrics present only where the run
                                   # computed this metric (an option of the run): without
                                   # it, tables leave the metric out

    @property
    def verdict_name(self) -> str:
        """The name the quality verdict withholds it under (metrics.quality)."""
        return self.group or self.name

    @property
    def ci_key(self) -> str | None:
        """Stored key of its 95 % interval (MEAN_CI entries and those with ``interval``)."""
        if self.aggregate is Aggregate.MEAN_CI:
            return f"{self.seed_key}_ci95"
        return f"{self.key}_ci95" if self.interval else None

    @property
    def key_prefixes(self) -> tuple[str, ...]:
        """Prefixes of every stored key (per seed and aggregated) that holds this metric."""
        return (self.seed_key or self.key, *self.withheld_keys)

    def better(self, a: float, b: float) -> bool:
        """Whether value ``a`` is strictly better than ``b``."""
        return a < b if self.direction == "lower" else a > b

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "label": self.label, "description": self.description,
                "direction": self.direction, "aggregate": self.aggregate.value,
                "key": self.key, "seed_key": self.seed_key, "ci_key": self.ci_key,
                "unit": self.unit, "log_axis": self.log_axis, "needs_k2": self.needs_k2,
                "verdict_name": self.verdict_name, "field": self.field,
                "ci_field": f"{self.field}_ci95" if self.field and self.ci_key else None,
                "sweep_plot": self.sweep_plot}


def _efficiency(metrics: Mapping[str, Any]) -> float | None:
    """1 / (MRSE x seconds per frame) when MRSE is a usable number (> 0, finite)."""
    mrse = metrics.get("mrse_mean")
    if mrse is None or not (math.isfinite(mrse) and mrse > 0):
        return None
    return efficiency(mrse, metrics["seconds_per_frame"])


#: Every metric, in the order tables and plots show them (the NIRC paper's Fig. 13
#: order: MRSE, FLIP, rBias², rVar).
METRICS: tuple[Metric, ...] = (
    Metric("mse", "MSE", "mean squared error against the reference", "lower",
           Aggregate.MEAN, key="mse_mean", seed_key="mse", log_axis=True, ci_min_change=0.25),
    Metric("mrse", "MRSE", "mean relative squared error (X-R)^2/(R^2+eps)", "lower",
           Aggregate.MEAN_CI, key="mrse_mean", seed_key="mrse", log_axis=True, field="mrse",
           sweep_plot=True, details=(("MRSE less reference floor", "mrse_corrected"),),
           ci_min_change=0.25),
    Metric("flip_hdr", "FLIP", "HDR-FLIP mean over pixels, at the reference's exposures",
           "lower", Aggregate.MEAN, key="flip_hdr_mean", seed_key="flip_hdr", group="flip",
           field="flip", sweep_plot=True, ci_min_change=0.1),
    Metric("flip_ldr", "FLIP (LDR)", "LDR-FLIP mean over pixels of the tone-mapped images",
           "lower", Aggregate.MEAN, key="flip_ldr_mean", seed_key="flip_ldr", group="flip",
           ci_min_change=0.1),
    Metric("rbias2", "rBias²", "relative squared bias, less the render and reference noise "
           "floors: the mean of the caches' own values for a method that trains a cache "
           "per seed, else pooled over the K renders", "lower", Aggregate.BIAS_VARIANCE,
           key="rbias2", log_axis=True, needs_k2=True, field="rbias2", sweep_plot=True,
           withheld_keys=("noise_floor",), interval=True,
           details=(("rBias² basis", "rbias2_basis"), ("rBias² pooled over seeds",
                                                        "rbias2_pooled"),
                    ("rBias² (raw, pooled)", "rbias2_raw"))),
    Metric("rvar", "rVar", "relative variance of one render over K renders", "lower",
           Aggregate.BIAS_VARIANCE, key="rvar", log_axis=True, needs_k2=True, field="rvar",
           sweep_plot=True, interval=True),
    Metric("rbias2_per_cache", "rBias² per cache", "rBias² of each seed's cache from its own "
           "frames, mean over caches", "lower", Aggregate.PER_CACHE,
           key="rbias2_per_cache_mean", group="rbias2", log_axis=True,
           details=(("rBias² per cache (std)", "rbias2_per_cache_std"),)),
    Metric("efficiency", "efficiency", "1 / (MRSE x seconds per frame)", "higher",
           Aggregate.DERIVED, key="efficiency", derive=_efficiency, unit="1/s",
           log_axis=True),
    Metric("v_rel", "V_rel(<F_r>)", "relative variance of the residual estimator at the "
           "primary hit, S²/(R²+eps) per pixel, mean over pixels (two-level methods)",
           "lower", Aggregate.MEAN_CI, key="v_rel_mean", seed_key="v_rel", log_axis=True,
           group="rvar", requires="v_rel_mean"),
    Metric("psnr", "PSNR", "PSNR of the tone-mapped images (clamp + sRGB), "
           "10 log10(1/MSE) on [0, 1]", "higher", Aggregate.MEAN, key="psnr_mean",
           seed_key="psnr", per_seed=psnr_tonemapped, unit="dB", field="psnr",
           ci_min_change=0.05),
    # After Intel Open Image Denoise, where the run asks for it (metrics.denoised).
    *(Metric(f"denoised_{name}_{what}", f"{label} denoised ({frames})",
             f"{quantity} after Intel Open Image Denoise of {description} (runs with "
             "denoised on)", "lower", Aggregate.MEAN, key=f"denoised_{name}_{what}_mean",
             seed_key=f"denoised_{name}_{what}", group=group, log_axis=name == "mrse",
             requires=DENOISER_KEY)
      for what, frames, description in (
          ("frame", "1 frame", "each of a seed's last four frames alone, mean over the "
                               "frames"),
          ("accum", "4 frames", "the mean of a seed's last four frames"))
      for name, label, quantity, group in (("mrse", "MRSE", "MRSE", "mrse"),
                                           ("flip", "FLIP", "HDR-FLIP", "flip"))),
)

BY_NAME: dict[str, Metric] = {m.name: m for m in METRICS}
if len(BY_NAME) != len(METRICS):
    raise RuntimeError("metric names in METRICS must be unique")

#: The metrics shown in result rows (API, sweep rows, report, dashboard), in order.
LISTED: tuple[Metric, ...] = tuple(m for m in METRICS if m.field)
#: The metrics with a value per seed, in order.
PER_SEED: tuple[Metric, ...] = tuple(m for m in METRICS if m.seed_key)
#: The metrics nirc-bench ci compares (a per-seed value and a minimum change), in order.
CI_GATED: tuple[Metric, ...] = tuple(m for m in PER_SEED if m.ci_min_change is not None)


def verdict_keys() -> dict[str, tuple[str, ...]]:
    """Verdict name -> prefixes of the stored keys it covers (metrics.quality.METRIC_KEYS)."""
    keys: dict[str, tuple[str, ...]] = {}
    for m in METRICS:
        have = keys.setdefault(m.verdict_name, ())
        # A prefix already covered (rbias2 covers rbias2_per_cache_mean) is not repeated.
        keys[m.verdict_name] = have + tuple(p for p in m.key_prefixes if not p.startswith(have))
    return keys


def per_seed_values(test: np.ndarray, ref: np.ndarray) -> dict[str, float | None]:
    """The per-seed values of the metrics with their own ``per_seed`` function."""
    return {m.seed_key: m.per_seed(test, ref) for m in PER_SEED if m.per_seed is not None}


def seed_mean(metric: Metric, per_seed: list[Mapping[str, Any]]) -> float | None:
    """Mean of ``metric``'s per-seed values (seeds without one left out; None if none has)."""
    values = [s.get(metric.seed_key) for s in per_seed]
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def metric_interval(metric: Metric, metrics: Mapping[str, Any]) -> tuple[list[float] | None,
                                                                           str | None]:
    """The 95 % interval of ``metric`` (one with a ``ci_key``) of a run's ``metrics`` and
    how it was made or why there is none; (None, None) when the metric has no value
    (withheld). rBias^2 and rVar read what was stored (metrics.bias_intervals); a MEAN_CI
    metric's is made from the stored per-seed values (metrics.statistics.interval_or_reason),
    so that runs stored before the log-scale interval read the same."""
    if metric.aggregate is not Aggregate.MEAN_CI:
        if metrics.get(metric.key) is None:
            return None, None
        if f"{metric.key}_ci_note" not in metrics:
            return None, f"no interval: stored before {metric.label} had one (metric version 3)"
        return metrics.get(metric.ci_key), metrics[f"{metric.key}_ci_note"]
    per_seed = metrics.get(f"{metric.seed_key}_per_seed")
    if per_seed:
        ci, note = interval_or_reason(per_seed)
        return (list(ci) if ci else None), note
    if metrics.get(metric.key) is None:
        return None, None
    stored = metrics.get(metric.ci_key)
    if stored and min(stored) >= 0:     # no per-seed values kept: the stored interval
        return list(stored), "95 % interval of the mean, as stored"
    if stored:
        return None, "no interval: the stored one crosses zero and the seeds' values are gone"
    return None, interval_or_reason([metrics[metric.key]] * int(metrics.get("k") or 1))[1]


#: Stored keys of estimates of a non-negative quantity less noise floors: unbiased, so
#: they can come out negative when the quantity is below what the noise resolves.
FLOOR_CORRECTED_KEYS = frozenset({"rbias2", "rbias2_per_cache_mean", "mrse_corrected"})


def below_noise_floor(key: str, value: Any) -> bool:
    """Whether the stored ``key``'s ``value`` is a noise-corrected estimate below zero:
    the quantity is smaller than the noise floors resolve (read it as ~0)."""
    return key in FLOOR_CORRECTED_KEYS and isinstance(value, int | float) and value < 0


def within_noise(key: str, value: Any, ci: Sequence[float] | None) -> bool:
    """Whether the stored noise-corrected ``key``'s ``value`` is not told apart from 0: its
    95 % interval ``ci`` holds 0 or, without one, the value is below 0
    (metrics.bias_intervals.bias_verdict)."""
    return (key in FLOOR_CORRECTED_KEYS and isinstance(value, int | float)
            and bias_verdict(value, ci) == "within noise")


def row_values(metrics: Mapping[str, Any]) -> dict[str, Any]:
    """A run's listed metrics under their ``field`` names (and ``<field>_ci95`` with
    ``<field>_ci_note``); ``below_noise_floor``: the fields whose noise-corrected value
    is negative; ``within_noise``: those whose interval holds 0 (:func:`within_noise`);
    ``rbias2_basis`` and ``bias_verdict`` (biased / within noise / None)."""
    row: dict[str, Any] = {}
    for m in LISTED:
        row[m.field] = metrics.get(m.key)
        if m.ci_key:
            row[f"{m.field}_ci95"], row[f"{m.field}_ci_note"] = metric_interval(m, metrics)
    row["below_noise_floor"] = [m.field for m in LISTED
                                if below_noise_floor(m.key, metrics.get(m.key))]
    row["within_noise"] = [m.field for m in LISTED if within_noise(
        m.key, metrics.get(m.key), row.get(f"{m.field}_ci95"))]
    row["rbias2_basis"] = metrics.get("rbias2_basis")
    row["bias_verdict"] = bias_verdict(metrics.get("rbias2"), row.get("rbias2_ci95"))
    return row


def metric_table() -> str:
    """The Markdown table of registered metrics (README.md, "Metrics"; checked by
    tests/metrics/test_registry.py; print it with ``python -m metrics.registry``)."""
    over_seeds = {Aggregate.MEAN: "mean", Aggregate.MEAN_CI: "mean, 95 % CI (log scale, K >= 3)",
                  Aggregate.BIAS_VARIANCE: "jointly", Aggregate.PER_CACHE: "per cache, mean",
                  Aggregate.DERIVED: "derived"}
    lines = ["| metric | what it is | better | over the K seeds | stored as |",
             "|---|---|---|---|---|"]
    for m in METRICS:
        unit = f" [{m.unit}]" if m.unit else ""
        k2 = " (K >= 2)" if m.needs_k2 else ""
        k2 += ", 95 % CI (K >= 3)" if m.interval else ""
        lines.append(f"| {m.label}{unit} | {m.description} | {m.direction} | "
                     f"{over_seeds[m.aggregate]}{k2} | `{m.key}` |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(metric_table())
