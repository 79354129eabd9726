"""A run's quality record: its facts gathered from the renders, judged by metrics.quality.

The executor calls :func:`judge_run` with the K accumulated images, the
reference, the scene's emitter count and the methods' statistics, stores the
returned record as the run's ``quality`` and sets the withheld metrics to None
(:func:`metrics.quality.withhold`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from metrics.checks import finite_pixel_mask
from metrics.quality import Quality, RunFacts, assess, image_facts


def run_facts(images: Sequence[np.ndarray], reference: np.ndarray, emitter_count: int | None,
              method_stats: Sequence[dict[str, Any] | None],
              reference_variance: np.ndarray | None = None) -> RunFacts:
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
        emitter_count=emitter_count,
        cache_steps=tuple(int(c.get("steps", 0)) for c in caches),
        cache_skipped_steps=tuple(int(c.get("skipped_steps", 0)) for c in caches),
        cache_records=tuple(int(c.get("records_seen", 0)) for c in caches),
        cache_dropped_nonfinite=tuple(int(c.get("dropped_nonfinite_targets", 0))
                                      + int(c.get("dropped_nonfinite_inputs", 0))
                                      for c in caches))


def quality_record(quality: Quality, facts: RunFacts) -> dict[str, Any]:
    """The run's ``quality`` JSON: the verdict, and the older ``finite`` /
    ``nonfinite_pixels`` keys kept for readers of runs stored before verdicts."""
    return {**quality.to_json(), "finite": facts.nonfinite_pixels == 0,
            "nonfinite_pixels": facts.nonfinite_pixels,
            "nonfinite_fraction": facts.nonfinite_fraction}


def judge_run(images: Sequence[np.ndarray], reference: np.ndarray, emitter_count: int | None,
              method_stats: Sequence[dict[str, Any] | None],
              reference_variance: np.ndarray | None = None) -> tuple[Quality, dict[str, Any]]:
    """(verdict, quality JSON) of a run; see the module docstring."""
    facts = run_facts(images, reference, emitter_count, method_stats, reference_variance)
    quality = assess(facts)
    return quality, quality_record(quality, facts)
