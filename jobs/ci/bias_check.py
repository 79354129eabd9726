"""The gate's bias check: rBias² and rVar of an entry with their 95 % intervals, and
the verdict on a method that claims to be unbiased (docs/ci.md, "Bias and variance").

rBias² and rVar have no per-seed values to test against a baseline (docs/metrics.md):
each run stores, per seed, the values whose mean is its estimate (``rbias2_seed_values``,
``rvar_seed_values``: the caches' own rBias² for a method that trains one per seed, else
the delete-one-seed jackknife pseudo-values of the pooled estimate;
metrics/bias_intervals.py). The entry's runs (its groups of seeds) are independent, so
their values are put together and the interval is made over all of them the way the
metrics make a run's (Student t for rBias², on the log scale for rVar); for one run it is
the run's own interval.

A method claims unbiasedness when the registry says so (``Method.unbiased``) or, where
its ``estimator`` parameter decides, that parameter is 'unbiased'. Its rBias² row is a
regression when the interval lies above 0: a bias is shown, whatever the baseline. Any
other row is shown beside the gate, not gated (verdict 'shown').
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from jobs.protocol.results import RunResultDetail
from metrics.bias_intervals import (
    BIAS_JACKKNIFE_NOTE,
    BIAS_PER_CACHE_NOTE,
    PER_CACHE,
    bias_interval,
    rvar_jackknife_interval,
)
from renderers.methods import METHODS


def claims_unbiased(method: str, params: dict[str, Any]) -> bool:
    """Whether ``method`` with ``params`` claims to be unbiased (module docstring)."""
    declared = METHODS[method].unbiased
    return declared if declared is not None else params.get("estimator") == "unbiased"


def _seed_values(results: Sequence[RunResultDetail], key: str) -> list[float] | None:
    """Every run's stored ``key`` values put together (None when a run has none)."""
    found: list[float] = []
    for result in results:
        values = result.metrics.get(key)
        if not values:
            return None
        found += [float(v) for v in values]
    return found


def rbias2_estimate(results: Sequence[RunResultDetail]
                    ) -> tuple[float | None, list[float] | None, str]:
    """rBias² over the entry's runs, its 95 % interval (or None) and how it was made."""
    values = _seed_values(results, "rbias2_seed_values")
    if values is None:
        if len(results) == 1:
            metrics = results[0].metrics
            return metrics.get("rbias2"), metrics.get("rbias2_ci95"), \
                str(metrics.get("rbias2_ci_note") or "no interval")
        return None, None, "a run stores no seed values of rBias² (fewer than 3 seeds)"
    per_cache = all(r.metrics.get("rbias2_basis") == PER_CACHE for r in results)
    ci, note = bias_interval(values, BIAS_PER_CACHE_NOTE if per_cache else BIAS_JACKKNIFE_NOTE)
    return float(np.mean(values)), ci, note


def rvar_estimate(results: Sequence[RunResultDetail]
                  ) -> tuple[float | None, list[float] | None, str]:
    """rVar over the entry's runs, its 95 % interval (or None) and how it was made: the
    runs' jackknife values put together, or one run's own interval (a chi-square one for
    a cache method's runs, which are not put together)."""
    if len(results) == 1:
        metrics = results[0].metrics
        return metrics.get("rvar"), metrics.get("rvar_ci95"), \
            str(metrics.get("rvar_ci_note") or "no interval")
    values = _seed_values(results, "rvar_seed_values")
    if values is None or any(r.metrics.get("rbias2_basis") == PER_CACHE for r in results):
        seeds = [len(r.per_seed) for r in results]
        rvars = [r.metrics.get("rvar") for r in results]
        if any(v is None or not np.isfinite(v) for v in rvars):
            return None, None, "a run has no finite rVar"
        return float(np.average(rvars, weights=seeds)), None, \
            "seed-weighted mean of the runs' rVar; no interval over several runs"
    estimate = float(np.mean(values))
    ci, note = rvar_jackknife_interval(estimate, values)
    return estimate, ci, note


def bias_verdict(unbiased: bool, rbias2_ci: Sequence[float] | None) -> tuple[str, str]:
    """(verdict, note) of the rBias² row: 'regression' when a method claiming to be
    unbiased has its interval above 0, 'pass' when it holds 0 (or reaches below), 'shown'
    for a method making no such claim."""
    if not unbiased:
        return "shown", "not gated: the method does not claim to be unbiased"
    if rbias2_ci is None:
        return "not comparable", "claims to be unbiased, but rBias² has no interval to tell"
    lo, hi = rbias2_ci
    if lo > 0:
        return "regression", (f"claims to be unbiased, but rBias²'s 95 % interval "
                              f"[{lo:.3g}, {hi:.3g}] lies above 0: biased")
    return "pass", f"unbiased within noise: rBias²'s 95 % interval [{lo:.3g}, {hi:.3g}] holds 0"
