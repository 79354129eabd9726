"""``nirc-bench ci``: run a pinned suite with sequential effort and compare it with a baseline.

Each entry of the suite (jobs.ci.ci_suite) is rendered in groups of
seeds (``seed_start + 0 .. group - 1``, then the next group, ...) until every
metric row of the entry is decided or the cap is reached; each group is one
stored run (with its commit and branch), so the history of results builds up
in the database. A row is compared only with a baseline row computed by the
same metric-definition and estimator versions on the same scene (fingerprint),
and frame time only on the same device; other rows are ``not comparable``.

The level of the whole suite (``suite.level``) is split evenly over its rows
(Bonferroni), and each row's share is spent over the looks
(jobs.ci.ci_stats): the chance that the suite fails while no row got worse by
its minimum change or more is at most ``suite.level``. docs/ci.md has the argument
and the chosen numbers.

Beside the compared rows, every entry has an rBias² and an rVar row with their 95 %
intervals over its runs (jobs.ci.bias_check); the rBias² row of a method that claims to
be unbiased is gated on its interval.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import Any, Literal, NamedTuple

from pydantic import BaseModel, Field

from jobs.ci.bias_check import bias_verdict, claims_unbiased, rbias2_estimate, rvar_estimate
from jobs.ci.ci_stats import (
    TEST_NAMES,
    accept_levels,
    compare,
    decide,
    look_levels,
    look_sizes,
    smallest_rank_p,
)
from jobs.ci.ci_suite import TIME, BaselineRow, Entry, Suite, config_key
from jobs.protocol.job import RenderJob
from jobs.protocol.provenance import git_branch, git_commit
from jobs.protocol.results import RunResultDetail, method_params
from jobs.record.store import Store
from metrics.registry import Metric
from metrics.statistics import mean_confidence_interval

#: Runs a typed job to completion and returns the stored run (embedded or over REST).
Runner = Callable[[RenderJob], RunResultDetail]
#: The baseline row of (entry, the entry's first candidate run, metric), or None.
BaselineSource = Callable[[Entry, RunResultDetail, Metric], BaselineRow | None]
#: 'shown': a row beside the gate (rBias² of a method not claiming unbiasedness, rVar).
Verdict = Literal["pass", "regression", "not comparable", "shown"]


class CiRow(BaseModel):
    """One metric of one entry: the comparison and its verdict."""

    entry: str
    scene: str
    method: str
    metric: str
    metric_label: str
    direction: Literal["lower", "higher"]
    min_change: float
    baseline: float | None = Field(None, description="mean of the baseline's seeds compared")
    candidate: float | None = Field(None, description="mean of the candidate's seeds")
    candidate_ci95: list[float] | None = Field(
        None, description="95 % interval of the candidate's value (Student t over its seeds; "
                          "rBias² and rVar: jobs.ci.bias_check)")
    change: float | None = Field(None, description="relative change (the estimate), "
                                                   "positive = worse")
    p_value: float | None = Field(None, description="one-sided p of 'worse by at most "
                                                    "min_change' (small: a regression)")
    level: float | None = Field(None, description="alpha_k of the deciding look")
    test: str | None = None
    seeds: int = Field(0, description="candidate seeds used")
    baseline_seeds: int = 0
    looks: int = 0
    verdict: Verdict
    note: str = ""


class GateCounts(NamedTuple):
    """A gate's rows by what became of them: ``compared`` were gated (pass or
    regression), of them ``regressions`` failed; ``not_comparable`` and ``shown`` (a
    bias check's row that is not gated) were not. Every report of the gate counts these."""

    compared: int
    regressions: int
    not_comparable: int
    shown: int


class CiResult(BaseModel):
    """What ``nirc-bench ci`` reports."""

    suite: str
    baseline: str = Field(description="the baseline compared with (file, or git ref)")
    commit: str
    branch: str | None
    level: float
    spending: str
    rows: list[CiRow]
    runs: list[int] = Field(description="ids of the runs stored by this invocation")
    seconds: float

    @property
    def regressions(self) -> list[CiRow]:
        return [row for row in self.rows if row.verdict == "regression"]

    @property
    def counts(self) -> GateCounts:
        verdicts = [row.verdict for row in self.rows]
        return GateCounts(verdicts.count("pass") + verdicts.count("regression"),
                          verdicts.count("regression"), verdicts.count("not comparable"),
                          verdicts.count("shown"))

    @property
    def exit_code(self) -> int:
        """0: no regression, 1: a regression."""
        return 1 if self.regressions else 0


def row_of(entry: Entry, results: Sequence[RunResultDetail], metric: Metric) -> BaselineRow:
    """``metric``'s per-seed values over ``results`` (runs of ``entry``; a later run's seed
    replaces an earlier one's), with what computed them (from the last run)."""
    by_seed: dict[int, float | None] = {}
    for result in results:
        for seed in result.per_seed:
            value = seed.metrics.get(metric.seed_key)
            by_seed[seed.seed] = (float(value) if isinstance(value, int | float)
                                  and math.isfinite(value) else None)
    last = results[-1]
    seeds = sorted(by_seed)
    return BaselineRow(
        label=entry.label, scene=entry.scene, scene_fingerprint=last.scene_fingerprint,
        method=entry.method, params=entry.params, resolution=entry.resolution, spp=entry.spp,
        frames=entry.frames, metric=metric.name, metric_version=last.metric_version,
        estimator_version=last.estimator_version, device_key=last.device_key, seeds=seeds,
        values=[by_seed[s] for s in seeds], commit=last.git_commit, branch=last.git_branch)


def not_comparable(base: BaselineRow | None, cand: BaselineRow, metric: Metric) -> str | None:
    """Why the candidate row cannot be compared with ``base`` (None: it can)."""
    if base is None:
        return "no baseline row for this configuration"
    for what in ("metric_version", "estimator_version"):
        if getattr(base, what) != getattr(cand, what):
            return (f"{what.replace('_', ' ')} {getattr(base, what)} (baseline) vs "
                    f"{getattr(cand, what)}: results of different versions are never compared")
    if base.scene_fingerprint != cand.scene_fingerprint:
        return "the scene changed (fingerprint differs from the baseline's)"
    if metric is TIME and base.device_key != cand.device_key:
        return (f"time is compared only on the same device (baseline {base.device_key}, "
                f"here {cand.device_key})")
    bad = [s for s, v in zip(base.seeds, base.values, strict=True) if v is None]
    if bad or len(base.values) < 2:
        return (f"the baseline has no finite value for seed(s) {bad}" if bad
                else "the baseline has fewer than 2 seeds")
    return None


class _RowState:
    """A row while its entry adds seeds."""

    def __init__(self, entry: Entry, metric: Metric, min_change: float) -> None:
        self.row = CiRow(entry=entry.label, scene=entry.scene, method=entry.method,
                         metric=metric.name, metric_label=metric.label,
                         direction=metric.direction, min_change=min_change,
                         verdict="not comparable")
        self.metric = metric
        self.base: BaselineRow | None = None
        self.decided = False
        self.blind_looks: list[int] = []     # looks whose level no rank test could reach

    def close(self, verdict: Verdict, note: str = "") -> None:
        self.row.verdict, self.row.note, self.decided = verdict, note, True

    def look(self, cand: BaselineRow, suite: Suite, levels: tuple[float, float], look: int,
             last: bool) -> None:
        """Compare with the candidate's seeds so far at ``levels`` (alpha_k, beta_k);
        decide if possible."""
        base = self.base
        missing = [s for s, v in zip(cand.seeds, cand.values, strict=True) if v is None]
        self.row.seeds, self.row.looks = len(cand.seeds), look
        if missing:
            self.close("regression", f"no finite value for candidate seed(s) {missing} "
                                     "(withheld by the quality verdict or not finite)")
            return
        base_values = dict(zip(base.seeds, base.values, strict=True))
        paired = all(s in base_values for s in cand.seeds)
        b = [base_values[s] for s in cand.seeds] if paired else list(base.values)
        minimum = self.row.min_change
        result = compare(cand.values, b, self.metric.direction, min_change=minimum,
                         paired=paired, test=suite.test)
        level, accept_level = levels
        self.row.baseline, self.row.candidate = result.baseline_mean, result.candidate_mean
        if len(cand.values) >= 2:
            self.row.candidate_ci95 = list(mean_confidence_interval(cand.values)[1:])
        self.row.change, self.row.p_value, self.row.level = result.change, result.p_worse, level
        self.row.test, self.row.baseline_seeds = TEST_NAMES[result.test], len(b)
        if result.test == "mann-whitney" and smallest_rank_p(len(cand.values), len(b)) >= level:
            self.blind_looks.append(look)
        verdict = decide(result, level, accept_level, last)
        estimate = f"estimate {result.change:+.1%}"
        if verdict == "regression":
            self.close(verdict, f"worse by at least {minimum:.0%} ({estimate}), "
                                f"p {result.p_worse:.2g} < {level:.2g}")
        elif verdict == "pass" and result.p_within < accept_level:
            self.close(verdict, f"change below {minimum:.0%} ({estimate}), "
                                f"p {result.p_within:.2g} < {accept_level:.2g}")
        elif verdict == "pass":
            blind = (f"; the Mann-Whitney test could not reject at look(s) {self.blind_looks} "
                     "with so few seeds, whatever the values" if self.blind_looks else "")
            self.close(verdict, f"not shown to be worse by at least {minimum:.0%} at the seed "
                                f"cap ({estimate}){blind}")


def run_suite(suite: Suite, runner: Runner, baseline_of: BaselineSource, *, suite_name: str,
              baseline_name: str, seed_start: int = 0,
              progress: Callable[[str], None] | None = None) -> CiResult:
    """Run ``suite`` with sequential effort against ``baseline_of`` (see the module
    docstring); ``runner`` runs one group of seeds of an entry as one stored run."""
    started = time.monotonic()
    entries, metrics = suite.entries(), suite.gated()
    sizes = look_sizes(suite.group, suite.max_seeds)
    per_row = suite.level / (len(entries) * len(metrics))     # Bonferroni over the rows
    levels = list(zip(look_levels(sizes, per_row, suite.spending),
                      accept_levels(sizes, suite.beta), strict=True))
    rows: list[CiRow] = []
    runs: list[int] = []
    for entry in entries:
        results: list[RunResultDetail] = []
        states = [_RowState(entry, m, suite.min_change_of(m)) for m in metrics]
        for look, size in enumerate(sizes):
            done = sizes[look - 1] if look else 0
            if progress:
                progress(f"{entry.label}: seeds {done + 1}-{size}")
            results.append(runner(entry.job(size - done, seed_start + done)))
            runs.append(results[-1].id)
            for state in states:
                cand = row_of(entry, results, state.metric)
                if look == 0:
                    state.base = baseline_of(entry, results[0], state.metric)
                    reason = not_comparable(state.base, cand, state.metric)
                    if reason:
                        state.row.seeds, state.row.looks = len(cand.seeds), 1
                        state.close("not comparable", reason)
                if not state.decided:
                    state.look(cand, suite, levels[look], look + 1, look == len(sizes) - 1)
            if all(state.decided for state in states):
                break
        rows += [state.row for state in states]
        rows += bias_rows(entry, results)
    return CiResult(suite=suite_name, baseline=baseline_name, commit=git_commit(),
                    branch=git_branch(), level=suite.level, spending=suite.spending, rows=rows,
                    runs=runs, seconds=time.monotonic() - started)


def bias_rows(entry: Entry, results: Sequence[RunResultDetail]) -> list[CiRow]:
    """The entry's rBias² and rVar rows over its runs, with their intervals; rBias² gated
    for a method that claims to be unbiased (jobs.ci.bias_check)."""
    seeds = sum(len(r.per_seed) for r in results)
    rows = []
    for name, label, (value, ci, how) in (("rbias2", "rBias²", rbias2_estimate(results)),
                                          ("rvar", "rVar", rvar_estimate(results))):
        verdict, note = (bias_verdict(claims_unbiased(entry.method, entry.params), ci)
                         if name == "rbias2" else ("shown", "not gated"))
        rows.append(CiRow(entry=entry.label, scene=entry.scene, method=entry.method,
                          metric=name, metric_label=label, direction="lower", min_change=0.0,
                          candidate=value, candidate_ci95=ci, seeds=seeds,
                          looks=len(results), verdict=verdict,  # type: ignore[arg-type]
                          note=f"{note} ({how})"))
    return rows


def baseline_rows(suite: Suite, runner: Runner, *, seed_start: int = 0,
                  progress: Callable[[str], None] | None = None) -> list[BaselineRow]:
    """Every entry rendered once at the seed cap: the rows of a new baseline file."""
    rows = []
    for entry in suite.entries():
        if progress:
            progress(f"{entry.label}: {suite.max_seeds} seeds")
        result = runner(entry.job(suite.max_seeds, seed_start))
        rows += [row_of(entry, [result], metric) for metric in suite.gated()]
    return rows


def file_baseline(rows: Sequence[BaselineRow]) -> BaselineSource:
    """The rows of a baseline file as a baseline source."""
    index = {(config_key(row), row.metric): row for row in rows}
    return lambda entry, _first, metric: index.get((config_key(entry), metric.name))


def stored_baseline(store: Store, ref: str) -> BaselineSource:
    """The latest stored results of the commit or branch ``ref``: per entry, the runs of the
    newest commit under ``ref`` with the entry's configuration, stored before the entry's
    first candidate run (their seeds merged)."""
    loaded: dict[tuple[str, int], list[RunResultDetail]] = {}   # per entry, read once

    def runs_of(entry: Entry, first: RunResultDetail) -> list[RunResultDetail]:
        matching = [run for run in store.list_runs(scene=first.scene, method=entry.method,
                                                   git_ref=ref)
                    if run.id < first.id and run.status == "succeeded"
                    and _same_config(run, entry)]
        chosen = [run for run in matching if run.git_commit == matching[0].git_commit]
        return [RunResultDetail.of(store.get_run(run.id)) for run in reversed(chosen)]

    def find(entry: Entry, first: RunResultDetail, metric: Metric) -> BaselineRow | None:
        key = (entry.label, first.id)
        if key not in loaded:
            loaded[key] = runs_of(entry, first)
        return row_of(entry, loaded[key], metric) if loaded[key] else None

    return find


def _same_config(run: Any, entry: Entry) -> bool:
    """Whether the stored ``run`` (jobs.record.models.Run) ran ``entry``'s configuration."""
    return (method_params(run.params) == entry.params and run.width == run.height == entry.resolution
            and run.spp == entry.spp and run.frames == entry.frames)
