"""A run's quality record: its facts gathered from the renders, judged by metrics.quality.

The executor first replaces every NaN or infinite number of the run's record by
None (:func:`finite_record`: JSON has no NaN, PostgreSQL refuses the token, and
a silent null would read as a withheld metric), then calls :func:`judge_run`
with the K accumulated images, the reference, the scene's emitter count, the
methods' statistics and the paths of the values it replaced, stores the
returned record as the run's ``quality`` and sets the withheld metrics to None
(:func:`metrics.quality.withhold`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from metrics.checks import finite_pixel_mask
from metrics.quality import Quality, RunFacts, assess, image_facts


def finite_json(value: Any, path: str, found: list[str]) -> Any:
    """``value`` (JSON-like) with every NaN or infinite number replaced by None; the
    path of each one replaced (``path`` + keys and indices) is appended to ``found``."""
    if isinstance(value, float) and not math.isfinite(value):
        found.append(path)
        return None
    if isinstance(value, dict):
        return {k: finite_json(v, f"{path}.{k}", found) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite_json(v, f"{path}[{i}]", found) for i, v in enumerate(value)]
    return value


def finite_record(metrics: dict[str, Any], per_seed: Sequence[dict[str, Any]]
                  ) -> tuple[dict[str, Any], list[dict[str, Any]], list[str]]:
    """(metrics, per-seed values, paths of the NaN or infinite numbers they held), every
    such number replaced by None: ``metrics.<key>`` and ``seed <k>.<key>...`` (a seed's
    method statistics included, e.g. ``seed 0.method_stats.loss_history[3]``)."""
    found: list[str] = []
    clean = finite_json(metrics, "metrics", found)
    seeds = [finite_json(values, f"seed {values['seed']}", found) for values in per_seed]
    return clean, seeds, found


def run_facts(images: Sequence[np.ndarray], reference: np.ndarray, emitter_count: int | None,
              method_stats: Sequence[dict[str, Any] | None],
              reference_variance: np.ndarray | None = None,
              nonfinite_values: Sequence[str] = ()) -> RunFacts:
    """The facts of K renders against their reference (cache statistics of caching methods).

    A reference pixel whose variance is non-finite counts as a non-finite reference
    pixel, as it does for the metrics (metrics.errors skips it): a finite mean with an
    overflowing variance (radiance near float32's limit) must not leave the errors
    silently empty.
    """
    ref = image_facts(reference)
    variance_bad = 0
    if reference_variance is not None:
        mean_ok = finite_pixel_mask(reference)
        variance_bad = int(np.count_nonzero(mean_ok & ~finite_pixel_mask(reference_variance)))
    renders = [image_facts(image) for image in images]
    caches = [stats["cache_stats"] for stats in method_stats if stats and "cache_stats" in stats]
    return RunFacts(
        pixels=ref["pixels"], renders=len(renders),
        nonfinite_pixels=sum(r["nonfinite"] for r in renders),
        reference_nonfinite_pixels=ref["nonfinite"] + variance_bad,
        reference_variance_nonfinite_pixels=variance_bad, reference_black_pixels=ref["black"],
        reference_negative_pixels=ref["negative"],
        render_negative_pixels=sum(r["negative"] for r in renders),
        emitter_count=emitter_count, nonfinite_values=tuple(nonfinite_values),
        cache_steps=tuple(int(c.get("steps", 0)) for c in caches),
        cache_skipped_steps=tuple(int(c.get("skipped_steps", 0)) for c in caches),
        cache_min_steps=tuple(int(c.get("min_trained_steps", 0)) for c in caches),
        cache_records=tuple(int(c.get("records_seen", 0)) for c in caches),
        cache_dropped_nonfinite=tuple(int(c.get("dropped_nonfinite_targets", 0))
                                      + int(c.get("dropped_nonfinite_inputs", 0))
                                      for c in caches))


def quality_record(quality: Quality, facts: RunFacts) -> dict[str, Any]:
    """The run's ``quality`` JSON: the verdict, and the older ``finite`` /
    ``nonfinite_pixels`` keys kept for readers of runs stored before verdicts."""
    return {**quality.to_json(), "finite": facts.nonfinite_pixels == 0,
            "nonfinite_pixels": facts.nonfinite_pixels,
            "nonfinite_fraction": facts.nonfinite_fraction,
            "nonfinite_values": list(facts.nonfinite_values)}


def judge_run(images: Sequence[np.ndarray], reference: np.ndarray, emitter_count: int | None,
              method_stats: Sequence[dict[str, Any] | None],
              reference_variance: np.ndarray | None = None,
              nonfinite_values: Sequence[str] = ()) -> tuple[Quality, dict[str, Any]]:
    """(verdict, quality JSON) of a run; see the module docstring."""
    facts = run_facts(images, reference, emitter_count, method_stats, reference_variance,
                      nonfinite_values)
    quality = assess(facts)
    return quality, quality_record(quality, facts)
