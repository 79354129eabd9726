"""The statistics of ``nirc-bench ci``: one look of a row, and the group-sequential design.

A row compares one metric of one configuration: the baseline's per-seed values
``b_1..b_m`` with the candidate's ``c_1..c_n``. Signs are turned so that a
positive difference is *worse*: ``d = c - b`` for a metric where lower is
better, ``d = b - c`` where higher is better. The relative change is

    change = mean(d) / |mean(b)|                      (0.3 = 30 % worse)

and ``min_change`` (m) is the smallest change that matters. Each look runs two
one-sided SciPy tests of the *shifted* hypothesis "change = m", i.e. of
``E[worse c] = E[worse b] + m |E[b]|``: the candidate's values against the
baseline's values each moved by ``m b`` the worse way (``(1 + m) b`` for a
positive lower-is-better metric, ``(1 - m) b`` for a positive higher-is-better
one):

===============  ==========================================================
design           test
===============  ==========================================================
paired           both sides hold the same seed numbers: Student's t on the
                 per-seed differences to the moved baseline (``ttest_rel``)
unpaired         Welch's t (``metrics.statistics.welch_test``) or the
                 Mann-Whitney U test (``mannwhitneyu``), as the suite says
===============  ==========================================================

``p_worse`` is the p-value of "the change is at most m" against "worse by more
than m"; rejecting it says that the lower confidence bound of the change is
above m (a regression of at least the minimum change, not merely an estimate
above it). ``p_within`` is the p-value of "the change is at least m" against
"less than m"; rejecting it says that the upper confidence bound is below m.
Moving the baseline by its own values keeps the baseline's noise in the test
(the scale ``|mean(b)|`` is itself an estimate).

Identical values are decided without a test: all differences zero (or both
sides constant and equal) is change 0; a constant shift with no spread is the
change it is, compared with m directly.

Sequential effort (docs/ci.md): seeds come in groups, looks ``k = 1..K`` at
``n_k`` seeds, information fraction ``t_k = n_k / n_K``. The row's level
``alpha`` is spent by a Lan-DeMets spending function ``A(t)``

    O'Brien-Fleming type:  A(t) = 2 (1 - Phi(z_{1 - alpha/2} / sqrt(t)))
    Pocock type:           A(t) = alpha ln(1 + (e - 1) t)

and look ``k`` tests at ``alpha_k = A(t_k) - A(t_{k-1})``. Since the
``alpha_k`` sum to ``alpha``, the chance of a false regression at any look is
at most ``sum_k alpha_k = alpha`` by the union bound (Bonferroni over the
looks: conservative, valid whatever the correlation between looks), and that
holds for any true change up to m, not only for no change. The early-accept
level ``beta`` is spent the same way over the looks before the cap, with the
Pocock-type function (accepting early is what saves seeds, so it spends early):
``beta_k = B(t_k) - B(t_{k-1})``, so a change of at least m is accepted early
with probability at most ``beta``. A row is decided

* a regression when ``p_worse < alpha_k``;
* no regression early when ``p_within < beta_k`` (the change is shown to be
  smaller than what matters);
* no regression at the cap otherwise (worse by at least m was not shown).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from scipy import special, stats

from metrics.statistics import welch_test

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


def accept_levels(sizes: Sequence[int], beta: float) -> list[float]:
    """``beta_k`` of each look's early acceptance (Pocock-type spending, module
    docstring); the cap's is 0, since the cap passes whatever is undecided."""
    return [*look_levels(sizes, beta, "pocock")[:-1], 0.0]


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
    change: float           # relative change (the estimate), worse way positive
    p_worse: float          # one-sided: worse by more than min_change
    p_within: float         # one-sided: worse by less than min_change


def _relative(value: float, scale: float) -> float:
    if scale > 0.0:
        return value / scale
    return 0.0 if value == 0.0 else math.copysign(math.inf, value)


def compare(candidate: Sequence[float], baseline: Sequence[float], direction: Direction, *,
            min_change: float, paired: bool, test: UnpairedTest = "welch") -> Look:
    """Compare finite per-seed values (paired: equal lengths, same seeds in order).

    =============  ===========================================================
    ``direction``  which way is better for the metric (metrics.registry)
    ``min_change`` the relative change the two tests are shifted to
    ``paired``     use the per-seed differences (the two sides share seeds)
    ``test``       the unpaired test: ``welch`` or ``mann-whitney``
    =============  ===========================================================
    """
    c = np.asarray(candidate, dtype=float)
    b = np.asarray(baseline, dtype=float)
    sign = 1.0 if direction == "lower" else -1.0
    scale = abs(float(b.mean()))
    worse_c, worse_b = sign * c, sign * b        # larger is worse on both sides now
    # The baseline moved the worse way by min_change of its own magnitude: testing the
    # candidate against it tests "change = min_change" (module docstring).
    moved_b = worse_b + min_change * math.copysign(1.0, float(b.mean())) * b
    diff = float(worse_c.mean() - worse_b.mean())
    change = _relative(diff, scale)
    if paired:
        d = worse_c - worse_b
        if d.size < 2 or np.ptp(d) == 0.0:       # identical values or a constant shift
            p_worse, p_within = _no_spread(change, min_change)
        else:
            p_worse, p_within = _t_tails(stats.ttest_rel(worse_c, moved_b,
                                                         alternative="greater"))
        return Look("paired", float(b.mean()), float(c.mean()), change, p_worse, p_within)
    if min(c.size, b.size) < 2 or (np.ptp(c) == 0.0 and np.ptp(b) == 0.0):
        p_worse, p_within = _no_spread(change, min_change)
    elif test == "mann-whitney":
        # A rank statistic is discrete: each side is its own test.
        p_worse, p_within = (float(stats.mannwhitneyu(worse_c, moved_b,
                                                      alternative=alternative).pvalue)
                             for alternative in ("greater", "less"))
    else:
        p_worse, p_within = _t_tails(welch_test(worse_c, moved_b, alternative="greater"))
    return Look(test, float(b.mean()), float(c.mean()), change, p_worse, p_within)


def _t_tails(result: Any) -> tuple[float, float]:
    """(p of "greater", p of "less") from one SciPy t-test run for "greater": the t
    distribution is continuous, so the two add up to 1 (one test per look, not two)."""
    p_greater = float(result.pvalue)
    return p_greater, 1.0 - p_greater


def _no_spread(change: float, min_change: float) -> tuple[float, float]:
    """Without spread (identical values, a constant shift) the change is what it is:
    (p_worse, p_within) is 0 on the side of ``min_change`` it falls, 1 otherwise."""
    return (0.0 if change > min_change else 1.0), (0.0 if change < min_change else 1.0)


def smallest_rank_p(candidate_seeds: int, baseline_seeds: int) -> float:
    """The smallest one-sided p-value the Mann-Whitney U test of :func:`compare` can
    return with these seed counts: that of two samples that do not overlap. A look
    whose level is below it cannot reject, whatever the values (docs/ci.md)."""
    candidate = 2.0 + np.arange(candidate_seeds, dtype=float)
    baseline = 1.0 / (2.0 + np.arange(baseline_seeds, dtype=float))
    return compare(candidate, baseline, "lower", min_change=0.0, paired=False,
                   test="mann-whitney").p_worse


def decide(look: Look, level: float, accept_level: float, last: bool) -> str | None:
    """``regression``, ``pass`` or None (undecided: add seeds) at a look whose "worse by
    at least min_change" test runs at ``level`` (its ``alpha_k``) and whose early
    acceptance at ``accept_level`` (its ``beta_k``)."""
    if look.p_worse < level:
        return "regression"
    if look.p_within < accept_level or last:
        return "pass"
    return None
