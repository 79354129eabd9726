"""Runs without rendering for the ``nirc-bench ci`` tests: per-seed values drawn by a function."""

from __future__ import annotations

import itertools
import json
from collections.abc import Callable
from typing import Any

from jobs.ci.ci_suite import BaselineRow, Entry, Suite
from jobs.protocol.job import RenderJob
from jobs.protocol.results import RunResultDetail, SeedRow
from jobs.protocol.versions import estimator_version
from metrics import METRIC_VERSION

#: (entry label, seed) -> the seed's stored metrics
Draw = Callable[[str, int], dict[str, Any]]


def fake_run(run_id: int, method: str, seeds: dict[int, dict[str, Any]], *,
             device_key: str = "llvm:test", fingerprint: str = "fp",
             version: int | None = None) -> RunResultDetail:
    """A stored run as the CI reads it (only the fields it reads are set)."""
    return _RUN.model_copy(update={
        "id": run_id, "scene_fingerprint": fingerprint, "method": method,
        "estimator_version": version or estimator_version(method), "device_key": device_key,
        "per_seed": [SeedRow.model_construct(seed=s, metrics=m, timings={})
                     for s, m in seeds.items()]})


_RUN = RunResultDetail.model_construct(
    id=0, scene="cornell-box", scene_fingerprint="fp", method="pt",
    metric_version=METRIC_VERSION, estimator_version=1, device_key="llvm:test",
    git_commit="c0ffee", git_branch="main", per_seed=[], metrics={})


class FakeRunner:
    """A Runner whose seeds' metrics come from ``draw``; it counts the seeds it ran."""

    def __init__(self, suite: Suite, draw: Draw, **run_options: Any) -> None:
        self.labels = {(e.method, json.dumps(e.params, sort_keys=True)): e.label
                       for e in suite.entries()}
        self.draw, self.options = draw, run_options
        self.ids = itertools.count(1)
        self.seeds: dict[str, int] = {}

    def __call__(self, job: RenderJob) -> RunResultDetail:
        spec = job.spec
        label = self.labels[(spec.method, json.dumps(spec.params, sort_keys=True))]
        self.seeds[label] = self.seeds.get(label, 0) + spec.seeds
        seeds = range(spec.seed_start, spec.seed_start + spec.seeds)
        return fake_run(next(self.ids), spec.method, {s: self.draw(label, s) for s in seeds},
                        **self.options)


def baseline_row(entry: Entry, metric: str, values: list[float | None], *,
                 seeds: list[int] | None = None, **fields: Any) -> BaselineRow:
    """A baseline row of ``entry`` (versions and device as :func:`fake_run` gives them)."""
    return BaselineRow(**{
        "label": entry.label, "scene": entry.scene, "scene_fingerprint": "fp",
        "method": entry.method, "params": entry.params, "resolution": entry.resolution,
        "spp": entry.spp, "frames": entry.frames, "metric": metric,
        "metric_version": METRIC_VERSION, "estimator_version": estimator_version(entry.method),
        "device_key": "llvm:test", "seeds": seeds if seeds is not None else list(range(len(values))),
        "values": values, **fields})
