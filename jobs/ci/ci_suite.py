"""What ``nirc-bench ci`` runs and compares with: the suite (TOML) and the baseline file (JSON).

A suite names scenes, methods (with parameters), resolution, spp, frames and
the sequential design (docs/ci.md):

.. code-block:: toml

    scenes = ["cornell-box"]
    resolution = 32
    frames = 8
    metrics = ["mrse", "flip_hdr", "psnr"]   # registry names, or "time"
    level = 0.001          # false-failure level of the whole suite
    group = 4              # seeds added per look
    max_seeds = 16         # the cap

    [[methods]]
    label = "nirc biased"
    method = "nirc"
    params = { estimator = "biased" }

Every scene runs every method: one *entry* each. A baseline file holds, per
entry and metric, the per-seed values with what they were computed by
(versions, device, scene fingerprint, commit).
"""

from __future__ import annotations

import json
import math
import tomllib
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    field_validator,
    model_validator,
)

from jobs.ci.ci_stats import Spending, UnpairedTest
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from metrics.registry import CI_GATED, Aggregate, Metric
from renderers.methods import MethodError, format_validation_error, parse_params

#: Frame time as a CI metric: compared only between results of the same device.
TIME = Metric("time", "s/frame", "median seconds per frame of a seed", "lower",
              Aggregate.MEAN, key="seconds_per_frame", seed_key="seconds_per_frame",
              unit="s", ci_min_change=1.0)
#: The metrics a suite may name.
CI_METRICS: dict[str, Metric] = {m.name: m for m in (*CI_GATED, TIME)}
BASELINE_FORMAT = 1


class CiError(ValueError):
    """The suite or baseline cannot be used (the message says why): exit status 2."""


class SuiteMethod(BaseModel):
    """A method of the suite with its parameters."""

    model_config = ConfigDict(extra="forbid", strict=True)

    label: str | None = None
    method: str
    params: dict[str, Any] = Field(default_factory=dict)


class Entry(BaseModel):
    """One configuration of the suite: a method on a scene."""

    model_config = ConfigDict(frozen=True)

    label: str
    scene: str
    method: str
    params: dict[str, Any]      # the dump of ``method_params``, as stored with a run
    #: The method's parameter model, validated once when the suite is expanded.
    method_params: Any = Field(exclude=True, repr=False)
    resolution: int
    spp: int
    frames: int
    ref_spp: int

    def spec(self, seeds: int, seed_start: int) -> RenderSpec:
        return RenderSpec(scene=self.scene, method=self.method, params=self.params,
                          resolution=self.resolution, spp=self.spp, frames=self.frames,
                          seeds=seeds, seed_start=seed_start,
                          reference=ReferenceSpec(spp=self.ref_spp))

    def job(self, seeds: int, seed_start: int) -> RenderJob:
        """The typed job of ``seeds`` seeds from ``seed_start``: the parameters are the
        ones validated at expansion, not parsed again."""
        return RenderJob.of(self.spec(seeds, seed_start), self.method_params)


class Suite(BaseModel):
    """A pinned CI suite (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", strict=True)

    scenes: list[str] = Field(min_length=1)
    methods: list[SuiteMethod] = Field(min_length=1)
    resolution: int = Field(32, ge=1, le=8192)
    spp: int = Field(1, ge=1, le=1 << 16)
    frames: int = Field(8, ge=1, le=100_000)
    ref_spp: int = Field(1024, ge=8, le=1 << 24)
    #: The soak run after the gate (jobs.stress.soak's settings: resolution, frames,
    #: seeds, reference_spp), embedded runs only; None: no soak.
    soak: dict[str, int] | None = None
    metrics: list[str] = Field(default_factory=lambda: [m.name for m in CI_GATED], min_length=1)
    min_change: dict[str, float] = Field(
        default_factory=dict, description="per-metric overrides of the registry's ci_min_change")
    level: float = Field(0.001, gt=0.0, lt=0.5)
    spending: Spending = "obrien-fleming"
    test: UnpairedTest = "welch"
    beta: float = Field(0.05, gt=0.0, lt=0.5)
    group: int = Field(4, ge=2, le=1000)
    max_seeds: int = Field(16, ge=2, le=1000)

    @field_validator("metrics")
    @classmethod
    def _known_metrics(cls, names: list[str]) -> list[str]:
        unknown = [n for n in names if n not in CI_METRICS]
        if unknown:
            raise ValueError(f"unknown metric(s) {', '.join(unknown)}; a suite compares "
                             f"{', '.join(CI_METRICS)}")
        return names

    @model_validator(mode="after")
    def _consistent(self) -> Suite:
        if self.max_seeds < self.group:
            raise ValueError("max_seeds must be at least group")
        for name, value in self.min_change.items():
            if name not in self.metrics:
                raise ValueError(f"min_change.{name}: not among the suite's metrics")
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"min_change.{name} must be a positive number")
        return self

    def min_change_of(self, metric: Metric) -> float:
        return self.min_change.get(metric.name, metric.ci_min_change)

    def gated(self) -> list[Metric]:
        return [CI_METRICS[name] for name in self.metrics]

    _entries: list[Entry] | None = PrivateAttr(None)

    def model_copy(self, *, update: dict[str, Any] | None = None, deep: bool = False) -> Suite:
        """A copy with ``update``; its entries are expanded anew from its own fields."""
        copy = super().model_copy(update=update, deep=deep)
        copy._entries = None
        return copy

    def entries(self) -> list[Entry]:
        """Every scene with every method, parameters validated by the method: once per
        suite (the first call; later calls return the same entries)."""
        if self._entries is None:
            self._entries = self._expand()
        return self._entries

    def _expand(self) -> list[Entry]:
        entries = []
        for scene in self.scenes:
            for m in self.methods:
                method_params = parse_params(m.method, m.params)
                label = m.label or m.method
                entries.append(Entry(label=f"{label} @ {scene}" if len(self.scenes) > 1 else label,
                                     scene=scene, method=m.method,
                                     params=method_params.model_dump(mode="json"),
                                     method_params=method_params,
                                     resolution=self.resolution, spp=self.spp,
                                     frames=self.frames, ref_spp=self.ref_spp))
        labels = [e.label for e in entries]
        if len(set(labels)) != len(labels):
            raise CiError("suite: two methods have the same label; give each a distinct label")
        return entries


def load_suite(path: Path) -> Suite:
    """The suite at ``path``; CiError with the reason if it is missing or invalid."""
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise CiError(f"suite file {path} not found") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise CiError(f"suite file {path} is not valid TOML: {err}") from None
    try:
        suite = Suite.model_validate(data)
        suite.entries()
    except ValidationError as err:
        raise CiError(f"suite file {path}: {format_validation_error(err)}") from None
    except MethodError as err:
        raise CiError(f"suite file {path}: {err}") from None
    return suite


def config_key(item: Entry | BaselineRow) -> tuple[Any, ...]:
    """What a baseline row must match to be an entry's: the configuration that ran."""
    return (item.scene, item.method, json.dumps(item.params, sort_keys=True),
            item.resolution, item.spp, item.frames)


class BaselineRow(BaseModel):
    """One metric of one entry, per seed, with what computed it."""

    model_config = ConfigDict(extra="forbid")

    label: str
    scene: str
    scene_fingerprint: str
    method: str
    params: dict[str, Any]
    resolution: int
    spp: int
    frames: int
    metric: str
    metric_version: int
    estimator_version: int
    device_key: str
    seeds: list[int]
    values: list[float | None]      # None: withheld or not finite
    commit: str | None = None
    branch: str | None = None


class BaselineFile(BaseModel):
    """``ci/baseline.json``: rows written by ``nirc-bench ci --update-baseline``."""

    model_config = ConfigDict(extra="forbid")

    format: int = BASELINE_FORMAT
    created_at: datetime = Field(default_factory=lambda: datetime.now(UTC))
    rows: list[BaselineRow]


def read_baseline(path: Path) -> BaselineFile:
    """The baseline file at ``path``; CiError if missing or unreadable."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise CiError(f"baseline file {path} not found (write one with "
                      "`nirc-bench ci --update-baseline`)") from None
    try:
        baseline = BaselineFile.model_validate_json(text)
    except ValidationError as err:
        raise CiError(f"baseline file {path}: {format_validation_error(err)}") from None
    if baseline.format != BASELINE_FORMAT:
        raise CiError(f"baseline file {path} has format {baseline.format}; this version "
                      f"reads format {BASELINE_FORMAT}")
    return baseline


def write_baseline(path: Path, rows: list[BaselineRow]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(BaselineFile(rows=rows).model_dump_json(indent=1) + "\n")
