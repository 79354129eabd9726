"""95 % intervals of rBias^2 and rVar over K seeds, and which rBias^2 a run reports
(docs/metrics.md, "Intervals of rBias² and rVar").

Pooled over seeds (:func:`metrics.errors.bias_variance`), both values are U-statistics of
order 2 in the seeds. With e_k = X_k - R and the weighted Gram matrix of the seeds'
errors G_ij = mean_p w e_i e_j (w = 1 / (R^2 + eps)):

- rBias^2 + ref_floor = mean (M - R)^2 w - mean S^2 / K w = mean over pairs i != j of G_ij
  (expand (M - R)^2 = (1/K^2) sum_ij e_i e_j and S^2 = (sum_i e_i^2 - K (M - R)^2) / (K - 1))
- rVar = mean S^2 w = mean over pairs i != j of (G_ii + G_jj) / 2 - G_ij

Their standard errors come from the delete-one-seed jackknife (Quenouille 1956, Tukey
1958): theta_(-i) is the same mean over the pairs without seed i, and the pseudo-values
p_i = K theta - (K - 1) theta_(-i) have mean exactly theta (a U-statistic) and sample
variance K x the jackknife variance (Efron & Stein 1981: never too small in expectation).
The seeds are the unit, so the interval holds whatever the correlation between pixels
*within* a seed, as far as the K pseudo-values are near normal.

Per cache (:func:`metrics.errors.per_cache_bias_variance`), the K caches' own rBias^2_k
are independent draws of one cache's squared bias: their mean is the headline rBias^2 of
a method that trains a cache per seed, with the Student-t interval over the K values;
pooled, opposite biases of the caches would cancel.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from metrics.statistics import (
    MIN_INTERVAL_VALUES,
    chi2_variance_interval,
    log_scale_interval,
    mean_confidence_interval,
)

#: How each interval is made, as the tables and the API state it (``<key>_ci_note``).
BIAS_JACKKNIFE_NOTE = ("95 % interval: Student t (K-1 degrees of freedom) over the "
                       "delete-one-seed jackknife values of the pooled estimate")
BIAS_PER_CACHE_NOTE = ("95 % interval: Student t (K-1 degrees of freedom) over the K caches' "
                       "own rBias²")
RVAR_JACKKNIFE_NOTE = ("95 % interval on the log scale: delete-one-seed jackknife standard "
                       "error, Student t (K-1 degrees of freedom)")
RVAR_CHI2_NOTE = ("95 % chi-square interval on K-1 degrees of freedom (all pixels of a seed "
                  "share its cache, so the seeds, not the pixels, are the samples)")

#: ``rbias2_basis``: the headline rBias^2 is the mean of the caches' own values, or pooled.
PER_CACHE, POOLED = "per cache", "pooled"


def seed_gram(weighted_errors: np.ndarray) -> np.ndarray:
    """(K, K) G_ij = mean over elements of a_i a_j, for the rows a_k = sqrt(w) (X_k - R)."""
    return weighted_errors @ weighted_errors.T / weighted_errors.shape[1]


def _pair_means(off_diagonal: np.ndarray, trace: np.ndarray,
                k: int) -> tuple[np.ndarray, np.ndarray]:
    """(mean over ordered pairs i != j of G_ij, of (G_ii + G_jj)/2 - G_ij) for ``k`` seeds
    whose G sums to ``off_diagonal`` off the diagonal and ``trace`` on it."""
    pairs = k * (k - 1)
    return off_diagonal / pairs, ((k - 1) * trace - off_diagonal) / pairs


def jackknife_values(gram: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The K delete-one-seed pseudo-values of (rBias^2 + ref_floor) and of rVar from the
    seeds' Gram matrix (:func:`seed_gram`); their means are the pooled estimates."""
    k = gram.shape[0]
    trace = float(np.trace(gram))
    off_diagonal = float(gram.sum()) - trace
    diagonal = np.diag(gram)
    # Without seed i: its row and column (2 sum_j G_ij - 2 G_ii off the diagonal) and G_ii go.
    bias_all, rvar_all = _pair_means(np.float64(off_diagonal), np.float64(trace), k)
    bias_loo, rvar_loo = _pair_means(off_diagonal - 2.0 * (gram.sum(axis=1) - diagonal),
                                     trace - diagonal, k - 1)
    return k * bias_all - (k - 1) * bias_loo, k * rvar_all - (k - 1) * rvar_loo


def _no_interval(values: Sequence[float]) -> str | None:
    """Why ``values`` give no interval (too few, or not finite), or None."""
    count = len(values)
    if count < MIN_INTERVAL_VALUES:
        return (f"no interval: {count} seed{'s' if count != 1 else ''} (an interval needs "
                f"{MIN_INTERVAL_VALUES} or more)")
    if not np.isfinite(values).all():
        return "no interval: the seeds' values are not finite"
    return None


def bias_interval(values: Sequence[float], note: str) -> tuple[list[float] | None, str]:
    """The symmetric Student-t 95 % interval of the mean of ``values`` (seed or cache
    values of rBias^2, which may be negative), with ``note``; or None and why not."""
    reason = _no_interval(values)
    if reason:
        return None, reason
    _, low, high = mean_confidence_interval(values)
    return [low, high], note


def rvar_jackknife_interval(rvar: float, pseudo_values: Sequence[float]
                            ) -> tuple[list[float] | None, str]:
    """rVar's 95 % interval on the log scale from its jackknife values (it is positive)."""
    reason = _no_interval(pseudo_values) or (None if rvar > 0 else
                                             "no interval: rVar is 0 (the seeds agree)")
    if reason:
        return None, reason
    k = len(pseudo_values)
    standard_error = float(np.std(pseudo_values, ddof=1)) / math.sqrt(k)
    return list(log_scale_interval(rvar, standard_error, k - 1)), RVAR_JACKKNIFE_NOTE


def pooled_intervals(gram: np.ndarray, rvar: float, ref_floor: float) -> dict[str, Any]:
    """The pooled estimates' seed values (jackknife), intervals and notes, as stored:
    ``rbias2_seed_values`` (their mean is the pooled rBias^2), ``rbias2_ci95``,
    ``rbias2_ci_note``, and the same three for ``rvar``; ``rbias2_basis`` = pooled.
    With K < 3 seeds (a delete-one-seed estimate needs 2) the values are None."""
    k = gram.shape[0]
    if k < MIN_INTERVAL_VALUES:
        reason = _no_interval([0.0] * k)
        return {"rbias2_basis": POOLED, "rbias2_seed_values": None, "rbias2_ci95": None,
                "rbias2_ci_note": reason, "rvar_seed_values": None, "rvar_ci95": None,
                "rvar_ci_note": reason}
    with np.errstate(over="ignore", invalid="ignore"):
        bias_values, rvar_values = jackknife_values(gram)
    bias_values = [float(v) - ref_floor for v in bias_values]
    rvar_values = [float(v) for v in rvar_values]
    rbias2_ci, rbias2_note = bias_interval(bias_values, BIAS_JACKKNIFE_NOTE)
    rvar_ci, rvar_note = rvar_jackknife_interval(rvar, rvar_values)
    return {"rbias2_basis": POOLED, "rbias2_seed_values": bias_values,
            "rbias2_ci95": rbias2_ci, "rbias2_ci_note": rbias2_note,
            "rvar_seed_values": rvar_values, "rvar_ci95": rvar_ci, "rvar_ci_note": rvar_note}


def per_cache_headline(metrics: Mapping[str, Any]) -> dict[str, Any]:
    """For a method that trains a cache per seed: the headline ``rbias2`` is the mean of the
    caches' own values (``rbias2_per_cache``) with the t interval over the K caches, and
    rVar's interval is the chi-square one on K - 1 degrees of freedom (the pixels of a
    seed share one cache, which the jackknife's near-normal pseudo-values do not survive:
    docs/metrics.md). Nothing changes (an empty dict) without per-cache values."""
    per_cache = metrics.get("rbias2_per_cache")
    if not per_cache:
        return {}
    rbias2_ci, rbias2_note = bias_interval(per_cache, BIAS_PER_CACHE_NOTE)
    updates: dict[str, Any] = {
        "rbias2": float(np.mean(per_cache)), "rbias2_basis": PER_CACHE,
        "rbias2_seed_values": list(per_cache), "rbias2_ci95": rbias2_ci,
        "rbias2_ci_note": rbias2_note}
    rvar, k = metrics.get("rvar"), int(metrics.get("k") or 1)
    if rvar is not None and math.isfinite(rvar) and k >= MIN_INTERVAL_VALUES:
        updates["rvar_ci95"] = list(chi2_variance_interval(rvar, k - 1))
        updates["rvar_ci_note"] = RVAR_CHI2_NOTE
    return updates


def bias_verdict(value: float | None, ci: Sequence[float] | None) -> str | None:
    """'biased' when rBias^2's 95 % interval lies above 0, 'within noise' when it holds 0
    (or, without an interval, the estimate is below 0); None when it cannot be said."""
    if value is None:
        return None
    if ci is not None:
        return "biased" if ci[0] > 0 else "within noise"
    return "within noise" if value < 0 else None
