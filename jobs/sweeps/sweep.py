"""Sweeps: the adaptive equal-bias protocol (NIRC paper Sec. 6.3, Fig. 13) and parameter
sweeps (the N_c sweep of biased NIRC among them).

Adaptive equal-bias sweep, per caching method (NIRC, NRC) and seed k:

1. train a cache and render the converged image V of terminating every path
   into it at the first vertex v1 (a *snapshot*, jobs/sweeps/snapshots.py: computed
   once per scene/settings/seed, reused by every eps and every later sweep);
2. the per-pixel relative bias b_p of V against the reference R with the noise
   of both removed (metrics/bias_maps.py; V is rendered in independent passes
   for its variance, R stores its own), by ``bias_definition``:
   ``relative-mse`` (default) b_p^2 = max(0, mean_c [(V-R)^2 - Var V - Var R]
   / (R^2 + e)), e the metric epsilon, or ``authors``: per channel
   |V_c - R_c| / luminance(R), every channel must pass;
3. for every eps, the mask "use the cache at v1 where b_p < eps" (masks grow
   with eps); elsewhere, and at later vertices, the spread heuristic decides.
   NIRC is not used at v1 for delta lobes and NRC where the roughness is below
   0.0625, as in the paper (the integrators exclude those lanes);
4. K = ``seeds`` independent renders of ``frames`` 1-spp frames with the
   frozen cache give MRSE (mean over seeds, with its CI), FLIP, rBias^2, rVar,
   ms per frame, the average path length and the % indirect-radiance bounces.

Every eps of one seed renders with the same frame seeds (common random
numbers): points differ only where their masks differ. Every point warms up
before it is timed (its own untimed frames and seeds, so its images are those it
renders without): a new mask makes Dr.Jit trace and record the frozen frame anew
(no compilation: the kernel cache has it), which, with one warm-up per integrator,
fell in the timed frames of every later eps (measured at 16x16: 100-200 ms for the
first three frames, one per kernel-history state, against 3-15 ms after a warm-up,
on the shared 2-core machine). Timings are those of the render stage with
a frozen, converged cache (the paper trains for 2000 frames first); the
training time is reported with the snapshots.

Path statistics, from the per-path ``cache_depth`` AOV (exact at 1 spp, where
a pixel is one path) and the count of background paths (no surface vertex):

- ``ir_bounces_pct``: the average over paths that invoked the cache of
  (index of the invoking vertex - 1), in percent (the paper's Fig. 13 x axis
  as its text words it: "the averaged index of a vertex at which the path was
  invoked minus one");
- ``avg_path_length_authors``: the authors' public implementation logs this
  instead: per pixel s = 1 + index of the first vertex that queried the cache,
  s = 1 for paths that never query it, s = 0 for background pixels, averaged
  over all pixels; ``ir_bounces_pct_authors`` = 100 x mean (s - 1) over the
  non-background pixels (equal to 100 x (avg_path_length_authors - 1) when no
  pixel sees the background).

"NIRC equal time": for each eps, the NRC point with the closest rBias^2 (the
mean over caches of the per-cache rBias^2 when the run has it, else the
pooled rBias^2) gives a frame-time budget, and N_c at v1 of NIRC is calibrated
to the largest candidate whose median frame time fits it (within
``time_tolerance_ms``), measured on this device with seed 0's caches: the NRC
point's frame time is re-measured in every round, interleaved with the NIRC
candidates (jobs/protocol/calibration.py). A probe timed on a loaded machine is
left out and taken again, and the sweep stops with the reason when every try was
loaded, unless the spec allows loaded timings (``allow_loaded``, ``--allow-loaded``).
The calibration, with its spread, its ``capped`` / ``unstable`` flags and the probes
left out, is stored with the point.

Every point is a stored run whose idempotency key addresses what determines
it (scene, settings, snapshots, eps, device): an identical point is never
rendered twice, so re-running a sweep renders nothing new.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from pydantic import BaseModel, Field, computed_field

from jobs.protocol.calibration import LoadLog, calibrate
from jobs.protocol.executor import (
    Prepared,
    Progress,
    SeedRender,
    execute,
    prepare,
    render_seed,
    store_run,
)
from jobs.protocol.job import RenderJob
from jobs.protocol.results import RunResult, Skipped
from jobs.protocol.spec import SweepSpec
from jobs.record.artifacts import ArtifactStore, artifact_record, make_private_dir
from jobs.record.config import Settings
from jobs.record.store import Store
from jobs.sweeps.snapshots import Snapshot, get_or_make_snapshot
from metrics.bias_maps import bias_map, passes
from renderers.methods import (
    EQUAL_TIME_SUFFIX,
    equal_time_pairs,
    get_method,
    parse_params,
    series_label,
    sweep_series,
)
from renderers.methods.base import FrameHooks, render_stage, run_frames
from renderers.methods.cached import CACHE_AOVS
from renderers.seeding import digest

#: Series name -> label in tables and plots (from the registry: each method's sweep role).
SERIES_LABELS = {series: series_label(series) for series in sweep_series()}


class SweepRow(RunResult):
    """One line of the sweep table: a stored point's public result (jobs.protocol.results)
    with the sweep's own columns."""

    series: str = Field(description="the series' label (a method, or its equal-time series)")
    eps: float | None = Field(description="relative-bias threshold of the v1 mask (eps sweep)")
    nc: int | None = Field(description="N_c at v1 (null: the method has no N_c)")
    value: bool | int | float | str | None = Field(
        None, description="the swept parameter's value (parameter sweep)")
    rbias2_raw: float | None = None
    avg_path_length: float | None = Field(None, description="average path vertices")
    ir_bounces_pct: float | None = Field(None, description="% indirect-radiance bounces")
    avg_path_length_authors: float | None = None
    ir_bounces_pct_authors: float | None = None
    background_pct: float | None = None
    cache_at_v1_pct: float | None = Field(None, description="% of paths cached at v1")
    mask_pct: float | None = Field(None, description="% of pixels the v1 mask allows")
    render_key: str | None = Field(
        None, description="what the point renders whatever its eps (method, parameters, every "
                          "seed's mask and cache): rows with equal keys render the same images "
                          "(null: stored before it was recorded)")
    calibration: dict[str, Any] | None = Field(None, description="the equal-time calibration")
    calibration_capped: bool | None = None
    calibration_unstable: bool | None = None
    finite: bool = True

    @computed_field  # type: ignore[prop-decorator]
    @property
    def ms_frame(self) -> float | None:
        """Milliseconds per frame (the plots' and the dashboard's time axis)."""
        return None if self.seconds_per_frame is None else 1e3 * self.seconds_per_frame


class SweepSnapshot(BaseModel):
    """A trained cache a sweep used (jobs.sweeps.snapshots), with its cost."""

    method: str
    seed: int
    key: str
    id: int
    train_s_per_frame: float
    v1_render_s: float


class SweepResult(BaseModel):
    """What a finished sweep reports (also stored as the sweep row's result)."""

    sweep_id: int
    key: str
    kind: str
    scene: str
    device_key: str
    parameter: str | None = Field(None, description="the swept parameter (parameter sweep)")
    rows: list[SweepRow]
    skipped: list[Skipped]
    work: dict[str, int]
    # Summed work of the stage jobs the sweep ran as on the service ({} when it ran
    # whole); ``work`` is then only what the final sweep job did itself.
    stage_work: dict[str, int] = Field(default_factory=dict)
    snapshots: list[SweepSnapshot] = Field(default_factory=list)
    files: dict[str, str] = Field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return self.model_dump(mode="json")


class Point(NamedTuple):
    """A sweep point to render: its threshold, the method's parameters, its stored key, and
    what is stored with it besides (an equal-time point's calibration and matched run)."""

    eps: float
    params: Any
    key: str
    extra: dict[str, Any] | None = None


# ---------------------------------------------------------------------------
# Masks and path statistics
# ---------------------------------------------------------------------------

def v1_mask(bias: np.ndarray, threshold: float) -> np.ndarray:
    """Pixels that may use the cache at v1: relative bias below ``threshold``."""
    return passes(bias, threshold)


def ir_bounces_pct(cache_depth_fractions: dict[str, float] | None) -> float | None:
    """% indirect-radiance bounces from the fractions of paths per ``cache_depth``
    (1 + index of the invoking vertex; 0: no cache): mean (index - 1) over invoking paths."""
    if not cache_depth_fractions:
        return None
    invoking = {int(k): v for k, v in cache_depth_fractions.items() if int(k) >= 1}
    total = sum(invoking.values())
    if total <= 0:
        return None
    return 100.0 * sum((k - 1) * v for k, v in invoking.items()) / total


def avg_path_length_authors(cache_depth_fractions: dict[str, float] | None,
                            background_fraction: float | None) -> float | None:
    """The authors' average path length (module doc): mean over all pixels of
    s = cache_depth for paths that used the cache, 1 for paths that did not, 0 for
    background; None without the histogram or the background count."""
    if not cache_depth_fractions or background_fraction is None:
        return None
    fractions = {int(k): v for k, v in cache_depth_fractions.items()}
    never = max(0.0, fractions.get(0, 0.0) - background_fraction)  # foreground, no cache
    return never + sum(k * v for k, v in fractions.items() if k >= 1)


def ir_bounces_pct_authors(cache_depth_fractions: dict[str, float] | None,
                           background_fraction: float | None) -> float | None:
    """100 x mean (s - 1) over the non-background pixels, s as in
    :func:`avg_path_length_authors` (paths that never used the cache count 0 bounces)."""
    length = avg_path_length_authors(cache_depth_fractions, background_fraction)
    if length is None or background_fraction is None or background_fraction >= 1.0:
        return None
    foreground = 1.0 - background_fraction
    return 100.0 * (length - foreground) / foreground


def v1_fraction(cache_depth_fractions: dict[str, float] | None) -> float:
    """Fraction of all paths that terminated into the cache at v1."""
    return float((cache_depth_fractions or {}).get("1", 0.0))


# ---------------------------------------------------------------------------
# The sweep
# ---------------------------------------------------------------------------

class _Sweep:
    """The state of one sweep run (see the module docstring for the protocol)."""

    def __init__(self, spec: SweepSpec, store: Store, settings: Settings,
                 progress: Progress | None, whole: bool = True) -> None:
        """``whole``: this runs the whole sweep (else one stage of its task graph, which
        reports its own steps but not the sweep's overall bar)."""
        self.spec, self.store, self.settings = spec, store, settings
        self.report = progress or (lambda stage, done, total: None)
        self.whole = whole
        self.base = spec.base_render_spec()
        self.prepared: Prepared = prepare(RenderJob.parse(self.base), store, settings,
                                          progress)
        self.device_key = self.prepared.device["device_key"]
        self.work = {"reference_rendered": int(self.prepared.reference.rendered_now),
                     "snapshots_trained": 0, "snapshots_reused": 0, "points_rendered": 0,
                     "points_reused": 0, "calibrations": 0}
        self.snapshots: dict[tuple[str, int], Snapshot] = {}
        self.skipped: list[Skipped] = []
        self._probes: dict[tuple[str, int | None], Any] = {}  # probe integrators (method, N_c)
        self._bias: dict[str, np.ndarray] = {}  # relative-bias maps by snapshot key
        self._params: dict[tuple[str, int | None], Any] = {}  # validated, by (method, N_c)
        # One bar across the whole sweep: caches, then points (reused ones count too).
        n_points = (len(spec.eps or []) if spec.parameter is None
                    else len(spec.parameter.values) * len(spec.methods))
        equal_time_series = len(equal_time_pairs(spec.methods)) if spec.equal_time else 0
        self.units_total = (len(spec.methods) * (spec.seeds + n_points)
                            + n_points * equal_time_series
                            if spec.kind == "eps" else n_points)
        self.units_done = 0

    def advance(self, units: int = 1) -> None:
        self.units_done = min(self.units_total, self.units_done + units)
        if self.whole:
            self.report("sweep", self.units_done, self.units_total)

    # ---- parameters and keys ----

    def params(self, method: str, nc_v1: int | None = None) -> Any:
        """Validated parameters of a sweep point: what the method's sweep role declares
        for equal-bias points, and what it adds (NIRC: biased, N_c 1 or ``nc_v1`` at v1).
        Validated once per (method, N_c): the model is frozen, so it is shared."""
        if (method, nc_v1) not in self._params:
            role = get_method(method).sweep
            values: dict[str, Any] = {**self.spec.params, "max_depth": self.spec.max_depth,
                                      **role.equal_bias}
            values.update(role.point(nc_v1))
            self._params[(method, nc_v1)] = parse_params(method, values)
        return self._params[(method, nc_v1)]

    def by_content(self, spec: Any) -> dict[str, Any]:
        """A render spec as point keys address it: the scene by its content (fingerprint),
        not by the name it was given, so that a file scene named by its path (CLI) and by
        its stored copy's id (REST) keys the same points."""
        return {**spec.model_dump(mode="json"), "scene": self.prepared.scene.fingerprint}

    def point_key(self, series: str, eps: float, params: Any, extra: Any = None) -> str:
        return digest("sweep-point", series, self.by_content(self.base),
                      params.model_dump(mode="json"), self.spec.train_frames,
                      self.spec.v1_spp, float(eps), self.prepared.reference.key,
                      self.device_key, extra, self.spec.versions(), length=32)

    def render_key(self, method: str, params: Any, masks: list[np.ndarray]) -> str:
        """What a point renders, whatever its eps: the method, its parameters and every
        seed's v1 mask and cache (points with equal render keys render the same images,
        frame seeds being common to every eps)."""
        return digest("sweep-render", method, self.point_key(method, 0.0, params),
                      [hashlib.sha256(np.packbits(mask).tobytes()).hexdigest() for mask in masks],
                      [self.snapshot(method, seed).key for seed in range(self.spec.seeds)],
                      length=32)

    def point_job(self, method: str, params: Any) -> RenderJob:
        """The render job of a point: the sweep's base spec with ``method`` and its
        parameters, validated by the sweep (:meth:`params`, the spec's expansions)."""
        spec = self.base.model_copy(update={"method": method,
                                            "params": params.model_dump(mode="json")})
        return RenderJob.of(spec, params)

    # ---- snapshots and frozen integrators ----

    def snapshot(self, method: str, seed: int) -> Snapshot:
        if (method, seed) not in self.snapshots:
            label = f"{method} cache {seed + 1}/{self.spec.seeds}"
            snap = get_or_make_snapshot(
                self.store, self.settings, self.prepared, method,
                get_method(method).build, self.params(method), seed,
                train_frames=self.spec.train_frames, v1_spp=self.spec.v1_spp,
                eps=self.spec.metric_eps,
                progress=lambda done, total: self.report(label, done, total))
            self.work["snapshots_trained" if snap.created_now else "snapshots_reused"] += 1
            self.snapshots[(method, seed)] = snap
            self.advance()
        return self.snapshots[(method, seed)]

    def frozen_integrator(self, method: str, params: Any, snap: Snapshot) -> Any:
        """The render integrator of ``params`` with the snapshot's cache loaded (frozen)."""
        integrator, _trainer, cache = get_method(method).build(self.prepared.scene, params, 0)
        cache.load_inference_parameters(snap.weights)
        integrator.cache = cache
        return integrator

    def bias(self, snap: Snapshot) -> np.ndarray:
        """The snapshot's relative-bias map, noise-corrected with the variances of the v1
        image and of the reference (computed once; every eps and probe reuses it)."""
        if snap.key not in self._bias:
            reference = self.prepared.reference
            self._bias[snap.key] = bias_map(
                self.spec.bias_definition, snap.v1_image, reference.mean, self.spec.metric_eps,
                v_variance=snap.v1_variance, ref_variance=reference.variance)
        return self._bias[snap.key]

    def skip_reason(self, method: str) -> str | None:
        """Why ``method`` cannot be swept on this scene (None: it can)."""
        applies, reason = get_method(method).applies_to(self.prepared.scene.features)
        if not applies:
            return reason
        snap = self.snapshot(method, 0)
        if v1_fraction(snap.stats["path_stats"].get("cache_depth_fractions")) == 0.0:
            return ("no path can terminate into the cache at its first vertex on this scene "
                    "(every first hit is a delta lobe, too glossy, or misses the scene)")
        return None

    # ---- rendering points ----

    def render_points(self, method: str, series: str, points: list[Point]) -> dict[float, int]:
        """Render and store the points; all share one params value.

        Returns run ids by eps. Each point warms up (module docstring); eps vary in the
        inner loop.
        """
        params = points[0].params
        rendered: dict[float, list[SeedRender]] = {point.eps: [] for point in points}
        masks: dict[float, list[np.ndarray]] = {point.eps: [] for point in points}
        stage = f"{SERIES_LABELS[series]} points"
        total, done = self.spec.seeds * len(points), 0
        for seed in range(self.spec.seeds):
            snap = self.snapshot(method, seed)
            integrator = self.frozen_integrator(method, params, snap)
            bias = self.bias(snap)
            for point in points:
                mask = v1_mask(bias, point.eps)
                integrator.set_v1_mask(mask)
                seed_render = render_seed(
                    lambda hooks, seed=seed, integrator=integrator: run_frames(
                        render_stage(self.prepared.scene, integrator, 1),
                        seed_parts=(self.prepared.scene.fingerprint, method,
                                    params.model_dump(mode="json"), "sweep", seed),
                        frames=self.spec.frames, spp=1, aov_names=CACHE_AOVS, hooks=hooks),
                    self.prepared.reference.mean, self.spec.metric_eps, warmup=True,
                    first_frame=seed * self.spec.frames)
                seed_render.output.method_stats = {"snapshot": snap.key,
                                                   "mask_fraction": float(mask.mean())}
                rendered[point.eps].append(seed_render)
                masks[point.eps].append(mask)
                done += 1
                self.report(stage, done, total)
        run_ids = {}
        for point in points:
            extra = {"sweep": {"series": series, "eps": point.eps,
                               "mask_fraction": float(np.mean([m.mean()
                                                               for m in masks[point.eps]])),
                               "render_key": self.render_key(method, params, masks[point.eps]),
                               "snapshots": [self.snapshot(method, s).key
                                             for s in range(self.spec.seeds)],
                               **(point.extra or {})}}
            summary = store_run(self.point_job(method, params), self.prepared,
                                rendered[point.eps], self.store, self.settings,
                                idempotency_key=point.key, extra=extra)
            run_ids[point.eps] = summary.run_id
            self.work["points_rendered"] += 1
            self.advance()
        return run_ids

    def series(self, method: str) -> dict[float, Any] | None:
        """The stored runs of ``method`` at every eps, rendering the missing ones."""
        params = self.params(method)
        keys = {eps: self.point_key(method, eps, params,
                                    extra={"bias_definition": self.spec.bias_definition})
                for eps in self.spec.eps}
        runs = {eps: self.store.find_run_by_idempotency_key(key) for eps, key in keys.items()}
        pending = [Point(eps, params, keys[eps]) for eps, run in runs.items() if run is None]
        self.work["points_reused"] += len(keys) - len(pending)
        self.advance(len(keys) - len(pending) + (0 if pending else self.spec.seeds))
        if pending:
            reason = self.skip_reason(method)
            if reason:
                self.skipped.append(Skipped(method=method, reason=reason))
                return None
            for eps, run_id in self.render_points(method, method, pending).items():
                runs[eps] = self.store.get_run(run_id)
        return runs

    def equal_time_series(self, method: str, against: str, own: dict[float, Any],
                          budget_runs: dict[float, Any]) -> dict[float, Any]:
        """``method`` (NIRC) with the largest knob value (N_c at v1) that fits the frame time
        of the ``against`` (NRC) point with the closest rBias^2 (module docstring)."""
        series = method + EQUAL_TIME_SUFFIX
        knob = get_method(method).knob.name
        candidates = self.spec.nc_candidates()
        budget_points = [(matching_rbias2(run), run) for run in budget_runs.values()
                         if matching_rbias2(run) is not None]
        runs: dict[float, Any] = {}
        plan: dict[int, list[Point]] = {}
        for eps, run in own.items():
            rbias2 = matching_rbias2(run)
            if rbias2 is None or not budget_points:
                continue
            _, match = min(budget_points, key=lambda item: abs(item[0] - rbias2))
            match_eps = match.params["sweep"]["eps"]
            # Loaded probes allowed: another point than the quiet machine's (the key of
            # a calibration that leaves them out is the one from before the choice).
            key = self.point_key(series, eps, self.params(method),
                                 extra=[candidates, match.idempotency_key,
                                        self.spec.probe_frames, self.spec.time_tolerance_ms,
                                        self.spec.calibration_rounds, self.spec.time_max_spread,
                                        self.spec.bias_definition,
                                        *(["allow_loaded"] if self.spec.allow_loaded else [])])
            stored = self.store.find_run_by_idempotency_key(key)
            if stored is not None:
                runs[eps] = stored
                self.work["points_reused"] += 1
                self.advance()
                continue
            # The budget is the matched point's frame time re-measured in every
            # round (same probe as the candidates), not its stored render time.
            log = LoadLog(self.spec.allow_loaded)
            record = calibrate(
                knob, candidates, lambda nc, eps=eps, log=log: self.probe(method, eps, log, nc),
                lambda match_eps=match_eps, log=log: self.probe(against, match_eps, log),
                budget_source=f"{series_label(against)} frame time at eps {match_eps} "
                              f"(rBias2 {matching_rbias2(match):.3g}, run {match.id})",
                tolerance_s=self.spec.time_tolerance_ms / 1e3, device_key=self.device_key,
                rounds=self.spec.calibration_rounds, max_spread=self.spec.time_max_spread,
                probe_frames=self.spec.probe_frames)
            record.note_load(log.merged())
            record.left_out = log.left_out
            self.work["calibrations"] += 1
            plan.setdefault(record.chosen, []).append(Point(
                eps, self.params(method, record.chosen), key,
                extra={"calibration": record.to_json(), f"{knob}_v1": record.chosen,
                       f"matched_{against}_run": match.id}))
        for nc, points in plan.items():
            if self.params(method, nc) == self.params(method):
                # The method's own point (same parameters, same seeds): record, don't render.
                for point in points:
                    self.advance()
                    runs[point.eps] = self.store.clone_run(
                        own[point.eps].id, idempotency_key=point.key,
                        metrics_update={"sweep": {**own[point.eps].metrics["sweep"],
                                                  "series": series, **(point.extra or {})}})
                continue
            rendered = self.render_points(method, series, points)
            runs.update({eps: self.store.get_run(run_id) for eps, run_id in rendered.items()})
        return runs

    def probe(self, method: str, eps: float, log: LoadLog, nc: int | None = None) -> float:
        """Seconds per 1-spp frame of ``method`` (NIRC: with ``nc`` samples at v1) with the
        mask of ``eps`` (seed 0's cache), on a quiet machine: a probe timed loaded is left
        out and taken again unless the sweep allows loaded timings (``log``:
        jobs.protocol.calibration.LoadLog). Only an integrator's first probe warms up
        (compiles): a new mask is data, not a new kernel."""
        snap = self.snapshot(method, 0)
        first = (method, nc) not in self._probes
        if first:
            self._probes[(method, nc)] = self.frozen_integrator(
                method, self.params(method, nc), snap)
        integrator = self._probes[(method, nc)]
        integrator.set_v1_mask(v1_mask(self.bias(snap), eps))
        warmups = iter([first])         # a probe taken again is compiled already

        def timings() -> dict[str, Any]:
            return run_frames(render_stage(self.prepared.scene, integrator, 1),
                              seed_parts=("probe", method, nc, eps),
                              frames=self.spec.probe_frames, spp=1, aov_names=CACHE_AOVS,
                              hooks=FrameHooks(warmup=next(warmups, False))).timings

        seconds = log.quiet_seconds(timings, f"{series_label(method)}"
                                             f"{f' N_c {nc}' if nc else ''} at eps {eps}")
        self.report("calibration", self.work["calibrations"] + 1, len(self.spec.eps))
        return seconds

    def parameter_point(self, method: str, value: Any) -> Any:
        """The stored run of ``method`` at one value of a parameter sweep, rendering it
        if missing (every value with the same seeds and the sweep's reference)."""
        job = self.point_job(method, self.spec.parameter_point(method, value))
        key = self.parameter_point_key(job)
        run = self.store.find_run_by_idempotency_key(key)
        if run is not None:
            self.work["points_reused"] += 1
            return run
        summary = execute(job, self.store, self.settings, idempotency_key=key,
                          progress=self.report)
        self.work["points_rendered"] += 1
        return self.store.get_run(summary.run_id)

    def parameter_point_key(self, job: RenderJob) -> str:
        """The stored key of a parameter sweep's point ``job``: its spec, the device, the
        reference and the versions. An N_c sweep's points keep the keys they had as a
        study of their own (the same parameters), so they are found again."""
        kind = "sweep-nc-point" if self.spec.is_nc_sweep else "sweep-parameter-point"
        return digest(kind, self.by_content(job.spec), self.device_key,
                      self.prepared.reference.key, job.spec.versions(), length=32)


def matching_rbias2(run: Any) -> float | None:
    """The rBias^2 the equal-time series matches on: the mean over caches of the
    per-cache rBias^2 when the run has it (opposite biases of different caches do
    not cancel there), else the pooled rBias^2."""
    value = run.metrics.get("rbias2_per_cache_mean")
    return value if value is not None else run.metrics.get("rbias2")


# ---------------------------------------------------------------------------
# Rows, plots, storage
# ---------------------------------------------------------------------------

def primary_nc(nc: list[int] | int | None) -> int | None:
    """N_c at the primary hit: `nirc`'s per-vertex list starts with it, `ss-nirc`'s is one
    number."""
    return nc[0] if isinstance(nc, list) and nc else nc if isinstance(nc, int) else None


def point_row(series: str, eps: float | None, run: Any) -> SweepRow:
    """One line of the sweep table from a stored run."""
    m, stats = run.metrics, run.path_stats
    sweep = m.get("sweep", {})
    fractions = stats.get("cache_depth_fractions")
    background = stats.get("background_fraction")
    calibration = sweep.get("calibration")
    return SweepRow.of(
        run, series=SERIES_LABELS.get(series, series), eps=eps,
        nc=primary_nc(run.params.get("nc")), rbias2_raw=m.get("rbias2_raw"),
        avg_path_length=stats.get("avg_path_vertices"),
        ir_bounces_pct=ir_bounces_pct(fractions),
        avg_path_length_authors=avg_path_length_authors(fractions, background),
        ir_bounces_pct_authors=ir_bounces_pct_authors(fractions, background),
        background_pct=100.0 * background if background is not None else None,
        cache_at_v1_pct=100.0 * v1_fraction(fractions) if fractions else None,
        mask_pct=100.0 * sweep["mask_fraction"] if "mask_fraction" in sweep else None,
        render_key=sweep.get("render_key"),
        calibration=calibration,
        calibration_capped=calibration.get("capped") if calibration else None,
        calibration_unstable=calibration.get("unstable") if calibration else None,
        finite=run.quality.get("finite", True))


def _convergence_curves(sweep: _Sweep) -> dict[str, dict[str, Any]]:
    """Mean over seeds of each method's training convergence (cache at v1, 1 spp)."""
    curves: dict[str, dict[str, Any]] = {}
    for method in sweep.spec.methods:
        snaps = [snap for (m, _), snap in sorted(sweep.snapshots.items()) if m == method]
        if not snaps:
            continue
        entry: dict[str, Any] = {"method": method}
        for name in ("frame_mrse", "accumulated_mrse"):
            values = np.array([[np.nan if v is None else v for v in s.stats["convergence"][name]]
                               for s in snaps], dtype=float)
            with warnings.catch_warnings():  # an all-NaN frame stays NaN (not plotted)
                warnings.simplefilter("ignore", RuntimeWarning)
                entry[name] = [float(v) for v in np.nanmean(values, axis=0)]
        entry["frame"] = list(range(len(entry["frame_mrse"])))
        curves[f"{SERIES_LABELS[method]} (cache at v1, training)"] = entry
    return curves


def _draw_plots(sweep: _Sweep, result: SweepResult, out_dir: Path) -> dict[str, Path]:
    """The sweep's own figures (PNG) in ``out_dir``, by artifact kind."""
    # Matplotlib takes ~1 s to import: a process that draws no sweep plot does not.
    from jobs.views.plots import plot_convergence, plot_sweep

    title = f"{sweep.prepared.scene.name} ({sweep.device_key})"
    files: dict[str, Path] = {}
    rows = result.to_json()["rows"]
    if result.kind == "eps":
        files["fig13"] = plot_sweep(rows, out_dir / "sweep_fig13.png",
                                    f"Adaptive equal-bias sweep: {title}")
        files["fig10"] = plot_convergence(_convergence_curves(sweep),
                                          out_dir / "convergence_fig10.png",
                                          f"Error over training frames: {title}")
    if result.kind == "parameter" and all(
            isinstance(row["value"], int | float) for row in rows):
        files["parameter"] = plot_sweep(rows, out_dir / "sweep_parameter.png",
                                        f"Sweep over {result.parameter}: {title}",
                                        x_key="value", x_label=str(result.parameter))
    return files


def _write_outputs(sweep: _Sweep, result: SweepResult, out_dir: Path,
                   plots: bool) -> list[dict[str, Any]]:
    """result.json, and with ``plots`` the sweep's figures, into ``out_dir``; returns the
    figures' artifact records. The folders it creates are owner-only, as the rest of the
    data folder (a CLI sweep runs under the user's umask, the service under 077)."""
    make_private_dir(out_dir)
    files = _draw_plots(sweep, result, out_dir) if plots else {}
    artifacts = ArtifactStore(sweep.settings.artifacts_dir)
    records = []
    for kind, path in files.items():
        record = artifact_record(artifacts, path.read_bytes(), kind, ".png", "image/png")
        record.pop("seed")
        records.append(record)
    result.files = {name: str(path) for name, path in files.items()}
    result.files["result"] = str(out_dir / "result.json")
    (out_dir / "result.json").write_text(json.dumps(result.to_json(), indent=2, default=str))
    return records


def run_sweep(spec: SweepSpec, store: Store, settings: Settings,
              progress: Progress | None = None, out_dir: Path | None = None,
              stage_work: dict[str, int] | None = None, plots: bool = True) -> SweepResult:
    """Run (or resume, or re-assemble) a sweep; see the module docstring.
    ``stage_work``: the summed work of the stage jobs that ran before (service);
    ``plots``: draw the sweep's own figures (PNG files, stored as the sweep's artifacts;
    0.4-0.6 s of CPU a plot, and matplotlib's import the first time in a process).
    A caller that draws its own figure from the rows (``nirc-bench reproduce``) passes
    False: result.json is written either way."""
    for method in spec.methods:
        get_method(method)
    sweep = _Sweep(spec, store, settings, progress)
    key = spec.key(sweep.device_key)
    row = store.start_sweep(key=key, kind=spec.kind, scene_name=sweep.prepared.scene.name,
                            scene_fingerprint=sweep.prepared.scene.fingerprint,
                            spec=spec.model_dump(mode="json"), result={},
                            device_key=sweep.device_key, **spec.versions())
    try:
        rows = {"eps": _eps_rows, "parameter": _parameter_rows}[spec.kind](sweep)
        result = SweepResult(
            sweep_id=row.id, key=key, kind=spec.kind, scene=sweep.prepared.scene.name,
            parameter=spec.parameter.name if spec.parameter else None,
            device_key=sweep.device_key, rows=rows, skipped=sweep.skipped, work=sweep.work,
            stage_work=stage_work or {},
            snapshots=[SweepSnapshot(method=m, seed=s, key=snap.key, id=snap.id,
                                     train_s_per_frame=snap.stats["train_seconds_per_frame"],
                                     v1_render_s=snap.stats["v1_render_s"])
                       for (m, s), snap in sorted(sweep.snapshots.items())])
        target = out_dir or settings.data_dir / "sweeps" / f"sweep-{row.id}"
        artifacts = _write_outputs(sweep, result, target, plots)
    except BaseException as err:
        store.finish_sweep(row.id, status="failed", result={"error": str(err)},
                           finished_at=datetime.now(UTC))
        raise
    store.finish_sweep(row.id, status="succeeded", result=result.to_json(),
                       finished_at=datetime.now(UTC), artifacts=artifacts)
    return result


def _eps_rows(sweep: _Sweep) -> list[SweepRow]:
    series = {method: sweep.series(method) for method in sweep.spec.methods}
    for method, runs in series.items():   # every cache's training curve goes into the plots
        for seed in range(sweep.spec.seeds if runs else 0):
            sweep.snapshot(method, seed)
    rows = [point_row(method, eps, run) for method, runs in series.items() if runs
            for eps, run in sorted(runs.items())]
    if sweep.spec.equal_time:
        sweep.skipped += unpaired_equal_time(sweep.spec.methods)
    for method, against in equal_time_pairs(sweep.spec.methods) if sweep.spec.equal_time else []:
        if series.get(method) and series.get(against):
            equal_time = sweep.equal_time_series(method, against, series[method], series[against])
            rows += [point_row(method + EQUAL_TIME_SUFFIX, eps, run)
                     for eps, run in sorted(equal_time.items())]
        else:
            sweep.skipped.append(Skipped(method=method + EQUAL_TIME_SUFFIX,
                                         reason=f"needs both the {series_label(method)} and "
                                                f"the {series_label(against)} series"))
    return rows


def unpaired_equal_time(methods: list[str]) -> list[Skipped]:
    """The equal-time series a sweep over ``methods`` asks for (``equal_time``) but cannot
    have: a method whose budget method is not swept with it."""
    paired = dict(equal_time_pairs(methods))
    return [Skipped(method=method + EQUAL_TIME_SUFFIX,
                    reason=f"calibrated to the {series_label(against)} series' frame times: "
                           f"add {against} to the sweep's methods")
            for method in methods if method not in paired
            and (against := get_method(method).sweep.equal_time_against)]


def _parameter_rows(sweep: _Sweep) -> list[SweepRow]:
    """A sweep over one parameter: a series per method, a row per value (online training,
    ``train_frames`` pre-training where the method trains a cache)."""
    assert sweep.spec.parameter is not None
    rows = []
    for method in sweep.spec.methods:
        for value in sweep.spec.parameter.values:
            run = sweep.parameter_point(method, value)
            sweep.advance()
            rows.append(point_row(method, None, run).model_copy(update={"value": value}))
    return rows


def run_stage(spec: SweepSpec, task: dict[str, Any], store: Store, settings: Settings,
              progress: Progress | None = None) -> dict[str, int]:
    """Run one stage of ``spec``'s task graph (jobs/execution/graph.py): store what the sweep
    would otherwise make itself when it gets there. Returns the stage's work
    counters (as ``SweepResult.work``)."""
    sweep = _Sweep(spec, store, settings, progress, whole=False)   # prepares the reference
    match task["stage"]:
        case "reference":
            pass
        case "snapshot":
            sweep.snapshot(task["method"], int(task["seed"]))
        case "series":
            sweep.series(task["method"])
        case "parameter-point":
            sweep.parameter_point(task["method"], task["value"])
        case other:
            raise ValueError(f"unknown sweep stage {other!r}")
    return sweep.work
