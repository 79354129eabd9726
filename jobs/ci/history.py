"""The history of a metric over commits, with step changes (GET /api/v1/ci/history).

Stored runs carry the commit that produced them (``Run.git_commit``, written by
the executor from jobs/protocol/provenance.py). :func:`build_history` turns the
runs of one method on one scene into series of points, one point per commit:

* a **series** holds runs of one setting (resolution, spp, frames, protocol, and
  the run's label: its resolved method parameters not at their default and a sweep
  point's eps, jobs/protocol/labels.py); runs of another setting are another series,
  never a point of this one, so runs of two labels are never pooled;
* a **point** pools the metric's values of a commit's runs: one value per seed
  where the metric has one (``Metric.seed_key``), else the run's aggregate
  (rBias², rVar: one value per run). It reports the median, a distribution-free
  interval for the median (below) and ``n``; values a quality verdict withholds
  and non-finite values are counted, never pooled;
* consecutive points are **compared** only when both were computed by the same
  metric version, estimator version and scene definition (fingerprint); a
  change of any of them is a *break*, marked on the later point and never
  tested as a step.

Step test, per compared pair of consecutive points (a, b)::

    t = (mean_b - mean_a) / sqrt(s_a^2 / n_a + s_b^2 / n_b)          (Welch 1947)

(s² the unbiased sample variances) and the Welch-Satterthwaite degrees of freedom
``(s_a²/n_a + s_b²/n_b)² / ((s_a²/n_a)² / (n_a - 1) + (s_b²/n_b)² / (n_b - 1))``,
two-sided (``metrics.statistics.welch_test``). A pair with fewer than two values on a side is
not tested; a pair whose two samples are both constant has p = 1 if they are
equal and p = 0 otherwise. The p-values of all pairs tested in one answer are
adjusted by Holm's step-down procedure (Holm 1979)::

    p~_(i) = max_{j <= i} min(1, (m - j + 1) p_(j))      p_(1) <= ... <= p_(m)

and a pair with p~ <= ``alpha`` is a detected step: the family-wise chance of
any false step in a flat history is at most ``alpha``. Only adjacent commits
are compared, so a drift spread over many commits is not found
(docs/service.md, "CI history").

Interval for the median (order statistics): for sorted values x_(1..n),
``[x_(k), x_(n+1-k)]`` covers the median with probability
``1 - 2 P(Binomial(n, 1/2) <= k - 1)``; the largest k reaching 95 % is used, or
k = 1 (the range) when n < 6, with its own level reported as ``ci_level``.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Sequence
from datetime import datetime
from typing import Any

import numpy as np
from pydantic import BaseModel, Field
from scipy import stats

from jobs.protocol.labels import resolved_params, run_label
from jobs.protocol.results import method_params
from jobs.views.chart_groups import protocol_of
from metrics.registry import Metric
from metrics.statistics import welch_test

#: The family-wise error rate of the step test over one answer.
STEP_ALPHA = 0.05
#: At most this many runs (newest first) are read for one history.
MAX_HISTORY_RUNS = 20_000
#: A clean commit: a hash without '-dirty', not 'unknown'.
CLEAN_COMMIT = re.compile(r"^[0-9a-f]{7,64}$")
STEP_TEST = ("Welch's two-sided t-test between the values of consecutive commits of one "
             "series, Holm-adjusted over every pair tested in this answer")


class HistoryPoint(BaseModel):
    """One commit's runs of one setting: the metric's median, interval and the step test."""

    commit: str
    branches: list[str] = Field(description="branches the runs were made on (where recorded)")
    time: datetime = Field(description="when the commit's first run of this setting was stored")
    runs: list[int]
    n: int = Field(description="finite values pooled (seeds of all the commit's runs)")
    nonfinite: int = Field(0, description="values left out because they are NaN or infinite")
    withheld: int = Field(0, description="runs whose quality verdict withholds the metric")
    median: float | None
    ci: list[float] | None = Field(description="order-statistic interval for the median")
    ci_level: float | None = Field(description="its coverage (0.95 or more once n >= 6)")
    metric_version: int
    estimator_version: int
    scene_fingerprint: str
    device_keys: list[str]
    break_before: str | None = Field(
        None, description="why this point is not compared with the previous one")
    change: float | None = Field(None, description="median minus the previous point's")
    p_value: float | None = Field(None, description="step test against the previous point")
    p_holm: float | None = Field(None, description="p_value after Holm's adjustment")
    step: bool = Field(False, description="a detected step change (p_holm <= alpha)")


class HistorySeries(BaseModel):
    """The points of one setting, ordered by time."""

    resolution: list[int]
    spp: int
    frames: int
    protocol: str = Field(description="online training, or a sweep point's frozen cache "
                                      "(jobs/views/chart_groups.py)")
    label: str = Field(description="what defines the series' runs (jobs/protocol/labels.py)")
    params: dict[str, Any] = Field(description="the newest run's resolved method parameters")
    points: list[HistoryPoint]


class History(BaseModel):
    """A metric of one method on one scene over commits (GET /api/v1/ci/history)."""

    metric: str
    label: str
    unit: str
    direction: str
    scene: str
    method: str
    branch: str | None
    alpha: float
    test: str
    skipped_runs: int = Field(description="matching runs without a clean commit (none, "
                                          "'unknown' or '-dirty'), left out")
    series: list[HistorySeries]


def branch_of(run: Any) -> str | None:
    """The git branch a run was made on, when its provenance records one (runs stored
    before branches were recorded have none)."""
    return getattr(run, "git_branch", None) or None


def run_values(run: Any, metric: Metric) -> list[Any] | None:
    """The metric's values of a stored run: per seed where it has them, else the run's
    aggregate; None when the run's quality verdict withholds the metric."""
    if metric.verdict_name in (run.quality or {}).get("withheld", []):
        return None
    if metric.seed_key:
        per_seed = [s.metrics.get(metric.seed_key) for s in run.seed_results]
        per_seed = [v for v in per_seed if v is not None]
        if per_seed:
            return per_seed
    value = (run.metrics or {}).get(metric.key)
    return [] if value is None else [value]


def _finite(values: Iterable[Any]) -> tuple[list[float], int]:
    """The finite real values, and how many others there were."""
    finite, other = [], 0
    for v in values:
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
            finite.append(float(v))
        else:
            other += 1
    return finite, other


def median_interval(values: Sequence[float], level: float = 0.95
                    ) -> tuple[float | None, list[float] | None, float | None]:
    """(median, [x_(k), x_(n+1-k)], its coverage) of ``values`` (module docstring)."""
    n = len(values)
    if n == 0:
        return None, None, None
    x = np.sort(np.asarray(values, dtype=float))
    median = float(np.median(x))
    if n == 1:
        return median, None, None

    def covers(k: int) -> float:   # 1 - 2 P(Binomial(n, 1/2) <= k - 1)
        return float(1.0 - 2.0 * stats.binom.cdf(k - 1, n, 0.5))

    k = 1
    while k + 1 <= n // 2 and covers(k + 1) >= level:
        k += 1
    coverage = covers(k)
    return median, [float(x[k - 1]), float(x[n - k])], float(coverage)


def welch_p(a: Sequence[float], b: Sequence[float]) -> float | None:
    """Two-sided p-value of Welch's t-test between ``a`` and ``b``
    (:func:`metrics.statistics.welch_test`; None: n < 2 on a side). Two constant sides are
    equal (p 1) or a certain step (p 0): the t statistic is undefined there."""
    if len(a) < 2 or len(b) < 2:
        return None
    if np.ptp(a) == 0.0 and np.ptp(b) == 0.0:
        return 1.0 if a[0] == b[0] else 0.0
    return float(welch_test(b, a).pvalue)


def holm(pvalues: Sequence[float]) -> list[float]:
    """Holm's step-down adjustment of ``pvalues`` (same order as given)."""
    m = len(pvalues)
    adjusted = [0.0] * m
    running = 0.0
    for rank, index in enumerate(sorted(range(m), key=lambda i: pvalues[i])):
        running = max(running, min(1.0, (m - rank) * pvalues[index]))
        adjusted[index] = running
    return adjusted


def detect_steps(samples: Sequence[Sequence[float]], compared: Sequence[bool],
                 alpha: float = STEP_ALPHA) -> list[tuple[float | None, float | None, bool]]:
    """(p, Holm-adjusted p, step) of each point against the previous one.

    ``samples[i]``: the finite values of point i; ``compared[i]``: whether point i
    may be compared with point i - 1 (False for the first and after a break).
    """
    raw = [welch_p(samples[i - 1], samples[i]) if i and compared[i] else None
           for i in range(len(samples))]
    tested = [i for i, p in enumerate(raw) if p is not None]
    adjusted = dict(zip(tested, holm([raw[i] for i in tested]), strict=True))
    return [(raw[i], adjusted.get(i), i in adjusted and adjusted[i] <= alpha)
            for i in range(len(samples))]


def _break_reason(before: HistoryPoint, after: HistoryPoint) -> str | None:
    """What makes two consecutive points incomparable, or None."""
    changes = [f"{what} {a} -> {b}" for what, a, b in (
        ("metric version", before.metric_version, after.metric_version),
        ("estimator version", before.estimator_version, after.estimator_version),
        ("scene fingerprint", before.scene_fingerprint, after.scene_fingerprint)) if a != b]
    return "; ".join(changes) or None


def _point(commit: str, runs: list[Any], metric: Metric) -> tuple[HistoryPoint, list[float]]:
    pooled: list[Any] = []
    withheld = 0
    for run in runs:
        values = run_values(run, metric)
        if values is None:
            withheld += 1
        else:
            pooled += values
    finite, nonfinite = _finite(pooled)
    median, ci, level = median_interval(finite)
    first = runs[0]
    point = HistoryPoint(
        commit=commit, branches=sorted({b for r in runs if (b := branch_of(r))}),
        time=min(r.created_at for r in runs), runs=[r.id for r in runs], n=len(finite),
        nonfinite=nonfinite, withheld=withheld, median=median, ci=ci, ci_level=level,
        metric_version=first.metric_version, estimator_version=first.estimator_version,
        scene_fingerprint=first.scene_fingerprint,
        device_keys=sorted({r.device_key for r in runs}))
    return point, finite


def _setting(run: Any) -> str:
    return json.dumps([run.width, run.height, run.spp, run.frames, protocol_of(run.params),
                       run_label(run.method, run.params)])


def build_history(runs: Iterable[Any], metric: Metric, *, scene: str, method: str,
                  branch: str | None = None, resolution: tuple[int, int] | None = None,
                  device: str | None = None, limit: int = 100,
                  alpha: float = STEP_ALPHA) -> History:
    """The history of ``metric`` over the stored ``runs`` of one method on one scene.

    Runs are kept when they match ``branch``, ``resolution`` (width, height) and
    ``device`` (a device key) where given; each series keeps its newest ``limit``
    commits. Runs of one commit, setting and versions form a point.
    """
    groups: dict[str, dict[tuple[str, int, int, str], list[Any]]] = {}
    skipped = 0
    for run in runs:
        if (branch is not None and branch_of(run) != branch
                or resolution is not None and (run.width, run.height) != resolution
                or device is not None and run.device_key != device):
            continue
        commit = run.git_commit or ""
        if not CLEAN_COMMIT.match(commit):
            skipped += 1
            continue
        key = (commit, run.metric_version, run.estimator_version, run.scene_fingerprint)
        groups.setdefault(_setting(run), {}).setdefault(key, []).append(run)

    series: list[HistorySeries] = []
    samples: list[list[float]] = []
    for setting, by_commit in groups.items():
        points = sorted((_point(key[0], sorted(rs, key=lambda r: r.id), metric)
                         for key, rs in by_commit.items()),
                        key=lambda pair: (pair[0].time, pair[0].runs[0]))[-limit:]
        width, height, spp, frames, protocol, label = json.loads(setting)
        newest = max((run for runs in by_commit.values() for run in runs),
                     key=lambda run: run.id)
        series.append(HistorySeries(
            resolution=[width, height], spp=spp, frames=frames, protocol=protocol, label=label,
            params=resolved_params(newest.method, method_params(newest.params)),
            points=[p for p, _ in points]))
        samples += [values for _, values in points]

    flat = [p for s in series for p in s.points]
    compared = []
    for s in series:
        for i, point in enumerate(s.points):
            if i:
                point.break_before = _break_reason(s.points[i - 1], point)
                if (point.break_before is None and point.median is not None
                        and s.points[i - 1].median is not None):
                    point.change = point.median - s.points[i - 1].median
            compared.append(i > 0 and point.break_before is None)
    for point, (p, adjusted, step) in zip(flat, detect_steps(samples, compared, alpha),
                                          strict=True):
        point.p_value, point.p_holm, point.step = p, adjusted, step
    series.sort(key=lambda s: s.points[-1].time, reverse=True)
    return History(metric=metric.name, label=metric.label, unit=metric.unit,
                   direction=metric.direction, scene=scene, method=method, branch=branch,
                   alpha=alpha, test=STEP_TEST, skipped_runs=skipped, series=series)
