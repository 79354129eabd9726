"""The statistics of ``nirc-bench ci``: one look of a row, and the group-sequential design.

A row compares one metric of one configuration: the baseline's per-seed values
``b_1..b_m`` with the candidate's ``c_1..c_n``. Signs are turned so that a
positive difference is *worse*: ``d = c - b`` for a metric where lower is
better, ``d = b - c`` where higher is better. The relative change is

    change = mean(d) / |mean(b)|                      (0.3 = 30 % worse)

and the one-sided p-value tests "the candidate is worse" with a SciPy test:

===============  ==========================================================
design           test
===============  ==========================================================
paired           both sides hold the same seed numbers: Student's t on the
                 per-seed differences (as ``scipy.stats.ttest_rel``)
unpaired         Welch's t (as ``ttest_ind(equal_var=False)``) or the
                 Mann-Whitney U test (``mannwhitneyu``), as the suite says
===============  ==========================================================

The upper confidence bound of the change (early acceptance, below) is the one-sided
confidence interval of the same SciPy test (``TtestResult.confidence_interval``).

Identical values are decided without a test: all differences zero (or both
sides constant and equal) is p = 1; a constant shift with no spread is p = 0
when worse, 1 when better.

Sequential effort (docs/ci.md): seeds come in groups, looks ``k = 1..K`` at
``n_k`` seeds, information fraction ``t_k = n_k / n_K``. The row's level
``alpha`` is spent by a Lan-DeMets spending function ``A(t)``

    O'Brien-Fleming type:  A(t) = 2 (1 - Phi(z_{1 - alpha/2} / sqrt(t)))
    Pocock type:           A(t) = alpha ln(1 + (e - 1) t)

and look ``k`` tests at ``alpha_k = A(t_k) - A(t_{k-1})``. Since the
``alpha_k`` sum to ``alpha``, the chance of a false regression at any look is
at most ``sum_k alpha_k = alpha`` by the union bound (Bonferroni over the
looks: conservative, valid whatever the correlation between looks). A row is
decided

* a regression when ``p < alpha_k`` and ``change >= min_change``;
* no regression early when the one-sided ``1 - beta`` upper confidence bound
  of the change is below ``min_change`` (the change is shown to be smaller
  than what matters). Stopping to accept never adds a rejection, so it
  leaves the level as it is;
* no regression at the cap otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from scipy import special, stats

Direction = Literal["lower", "higher"]
Spending = Literal["obrien-fleming", "pocock"]
UnpairedTest = Literal["welch", "mann-whitney"]

TEST_NAMES = {"paired": "paired t", "welch": "Welch t", "mann-whitney": "Mann-Whitney U"}


def spent(t: float, alpha: float, spending: Spending) -> float:
    """``A(t)``: the level spent up to information fraction ``t`` in [0, 1]
    (Lan and DeMets 1983; the O'Brien-Fleming-type and Pocock-type functions)."""
    if t <= 0.0:
        return 0.0
    if spending == "obrien-fleming":   # 2 (1 - Phi(z_{1 - alpha/2} / sqrt(t)))
        return float(2.0 * special.ndtr(special.ndtri(alpha / 2.0) / math.sqrt(min(t, 1.0))))
    return float(alpha * math.log1p((math.e - 1.0) * min(t, 1.0)))


def look_levels(sizes: Sequence[int], alpha: float, spending: Spending) -> list[float]:
    """``alpha_k`` of each look at ``sizes[k]`` seeds (the last is the cap); they sum to
    ``alpha``."""
    cap = sizes[-1]
    fractions = [0.0, *(n / cap for n in sizes)]
    return [spent(b, alpha, spending) - spent(a, alpha, spending)
            for a, b in zip(fractions, fractions[1:], strict=False)]


def look_sizes(group: int, cap: int) -> list[int]:
    """Seeds after each look: ``group, 2 group, ...``, the last one the cap."""
    sizes = list(range(group, cap, group))
    return [*sizes, cap]


@dataclass(frozen=True)
class Look:
    """One row compared at one look."""

    test: str               # key of TEST_NAMES
    baseline_mean: float
    candidate_mean: float
    change: float           # relative change, worse way positive
    upper: float            # one-sided (1 - beta) upper bound of the change
    p_value: float          # one-sided: the candidate is worse


def _relative(value: float, scale: float) -> float:
    if scale > 0.0:
        return value / scale
    return 0.0 if value == 0.0 else math.copysign(math.inf, value)


def compare(candidate: Sequence[float], baseline: Sequence[float], direction: Direction, *,
            paired: bool, test: UnpairedTest = "welch", beta: float = 0.05) -> Look:
    """Compare finite per-seed values (paired: equal lengths, same seeds in order).

    =============  ===========================================================
    ``direction``  which way is better for the metric (metrics.registry)
    ``paired``     use the per-seed differences (the two sides share seeds)
    ``test``       the unpaired test: ``welch`` or ``mann-whitney``
    ``beta``       one-sided level of the upper bound that accepts early
    =============  ===========================================================
    """
    c = np.asarray(candidate, dtype=float)
    b = np.asarray(baseline, dtype=float)
    sign = 1.0 if direction == "lower" else -1.0
    scale = abs(float(b.mean()))
    worse_c, worse_b = sign * c, sign * b        # larger is worse on both sides now
    if paired:
        d = worse_c - worse_b
        diff = float(d.mean())
        if d.size < 2 or np.ptp(d) == 0.0:       # identical values or a constant shift
            p, upper = _no_spread(diff)
        else:
            p, upper = _t_tail(stats.ttest_1samp(d, 0.0, alternative="less"), beta)
        return Look("paired", float(b.mean()), float(c.mean()), _relative(diff, scale),
                    _relative(upper, scale), p)
    diff = float(worse_c.mean() - worse_b.mean())
    if min(c.size, b.size) < 2 or (np.ptp(c) == 0.0 and np.ptp(b) == 0.0):
        p, upper = _no_spread(diff)
    else:
        p, upper = _t_tail(stats.ttest_ind(worse_c, worse_b, equal_var=False,
                                           alternative="less"), beta)
        if test == "mann-whitney":
            p = float(stats.mannwhitneyu(worse_c, worse_b, alternative="greater").pvalue)
    return Look(test, float(b.mean()), float(c.mean()), _relative(diff, scale),
                _relative(upper, scale), p)


def _no_spread(diff: float) -> tuple[float, float]:
    """Without spread (identical values, a constant shift) the sign decides: (p, bound)."""
    return (0.0 if diff > 0 else 1.0), diff


def _t_tail(result: Any, beta: float) -> tuple[float, float]:
    """From SciPy's t-test of "the difference is less than 0" (``result``, a
    ``TtestResult``): the one-sided p-value of "worse" (difference > 0), which is its
    complement (the t distribution is continuous), and the (1 - beta) upper bound of
    the difference, its one-sided confidence interval's upper end."""
    return float(1.0 - result.pvalue), float(result.confidence_interval(1.0 - beta).high)


def decide(look: Look, level: float, min_change: float, last: bool) -> str | None:
    """``regression``, ``pass`` or None (undecided: add seeds) at a look tested at
    ``level`` (its ``alpha_k``)."""
    if look.p_value < level and look.change >= min_change:
        return "regression"
    if look.upper < min_change or last:
        return "pass"
    return None
