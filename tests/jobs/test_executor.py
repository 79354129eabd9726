"""The executor end to end on a tiny render: storage, reuse, provenance, quality flag."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
from pyoidn.version import oidn_version
from rich.console import Console

from jobs.protocol.executor import aggregate, execute, per_cache_metrics
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from jobs.record.config import Settings
from jobs.record.db import open_store
from metrics.statistics import RunningMoments
from renderers import methods
from service.tables import metrics_table

SPEC = RenderSpec(scene="cornell-box", resolution=8, spp=1, frames=2, seeds=3,
                  reference=ReferenceSpec(spp=64, spp_per_pass=8))


@pytest.fixture
def env(mi, data_dir):
    settings = Settings()
    return settings, open_store(settings)


def test_a_run_is_stored_with_seeds_artifacts_and_provenance(env):
    settings, store = env
    summary = execute(RenderJob.parse(SPEC), store, settings)

    run = store.get_run(summary.run_id)
    assert run.status == "succeeded" and run.method == "pt" and run.seeds == 3
    assert [s.seed for s in run.seed_results] == [0, 1, 2]
    assert run.metrics["k"] == 3 and run.metrics["mrse_mean"] > 0
    lo, hi = run.metrics["mrse_ci95"]
    assert lo <= run.metrics["mrse_mean"] <= hi
    assert run.metrics["rbias2"] == pytest.approx(
        run.metrics["rbias2_raw"] - run.metrics["noise_floor"] - run.metrics["ref_floor"])
    assert run.metrics["ref_floor"] > 0 and isinstance(run.metrics["warnings"], list)
    # Per cache from each seed's 2 frames.
    assert len(run.metrics["rbias2_per_cache"]) == len(run.metrics["rvar_per_cache"]) == 3
    assert run.metrics["rbias2_per_cache_mean"] == pytest.approx(
        np.mean(run.metrics["rbias2_per_cache"]))
    assert run.metrics["rbias2_per_cache_std"] is not None and run.metrics["rvar_per_cache_mean"] > 0
    assert run.metrics["per_cache_frames"] == 2 and run.metrics["per_cache_unavailable"] is None
    assert run.device_key == summary.device["device_key"]
    assert run.git_commit and run.versions["mitsuba"]
    # Denoising is off unless asked for: no denoised value, no denoiser, and the stored
    # spec is the one from before the option existed.
    assert "denoiser" not in run.metrics and "denoised" not in run.params["spec"]
    assert not any(key.startswith("denoised") for s in run.seed_results for key in s.metrics)
    text = Console(width=250, record=True)
    text.print(metrics_table(summary.result))
    assert "denois" not in text.export_text()
    assert "sync" in run.timings["protocol"] and run.timings["warmup_s"] > 0
    # One statistic over the 3 x 2 timed frames: the median frame's stages are the frame
    # time, and no stage's median exceeds it.
    timings = run.timings
    assert timings["frames"] == 6
    stages = {k: v for k, v in timings["breakdown"]["parts_s"].items() if k != "other"}
    assert sum(stages.values()) == pytest.approx(timings["seconds_per_frame"])
    assert run.metrics["seconds_per_frame"] == timings["seconds_per_frame"]
    assert all(s["median_s"] <= timings["seconds_per_frame"] for s in timings["stages"].values())
    assert 0 < timings["device_time"]["kernel_median_s"] <= timings["device_time"]["wall_median_s"]
    assert timings["load"]["loaded"] in (True, False)
    assert run.quality["verdict"] == "ok" and run.quality["finite"] is True
    assert run.quality["nonfinite_pixels"] == 0
    kinds = sorted(a.kind for a in run.artifacts)
    assert kinds.count("image") == 3 and "preview" in kinds and "error_map" in kinds
    for artifact in run.artifacts:
        assert (settings.artifacts_dir / artifact.path).is_file()


def test_a_cached_run_stores_its_time_breakdown_and_resolved_cache(env):
    settings, store = env
    spec = SPEC.model_copy(update={"method": "nirc", "seeds": 1,
                                   "params": {"cache": {"batch_size": 256}}})
    summary = execute(RenderJob.parse(spec), store, settings)
    run = store.get_run(summary.run_id)
    parts = run.timings["breakdown"]["parts_s"]
    assert {"render", "training_paths", "training", "other"} <= set(parts)
    assert all(seconds >= 0 for seconds in parts.values())
    assert run.timings["breakdown"]["inference_in_render"] == ("inference" not in parts)
    assert run.seed_results[0].timings["breakdown"] == run.timings["breakdown"]
    # The resolved configuration, not the overrides (the run's params say cache:
    # {batch_size: 256}): the preset's network with the override, and per frame the
    # 8x8 image's 4096-record floor, capped by the 256-record batch.
    assert run.params["cache"] == {"batch_size": 256}
    resolved = summary.result.model_dump(mode="json")["caches"]["cache"]
    assert resolved["config"]["batch_size"] == 256
    assert (resolved["config"]["mlp"]["width"], resolved["config"]["mlp"]["hidden_layers"],
            resolved["config"]["direction"]["sh_bands"]) == (64, 4, 5)
    assert resolved["config"]["optimizer"]["lr"] == 0.01
    budget = resolved["per_frame"]
    assert (budget["mode"], budget["steps"], budget["batch_size"]) == ("scaled", 4, 256)
    assert budget["records"] == 1024 and budget["paths"] >= 4096


def test_a_barely_trained_cache_is_not_ok(env):
    """4 steps a frame over the warm-up and 2 frames is 12 steps, below the 100 that
    nirc's weight EMA (0.99) needs; pre-trained for 22 frames the cache takes 100."""
    settings, store = env
    spec = SPEC.model_copy(update={"method": "nirc", "seeds": 1,
                                   "params": {"cache": {"batch_size": 64}}})
    short = execute(RenderJob.parse(spec), store, settings).quality
    assert short["verdict"] == "undertrained-cache" and short["withheld"] == []
    assert "steps (12) than their configuration needs to count as trained (100)" in \
        short["reasons"][0]["message"]
    trained = execute(RenderJob.parse(spec.model_copy(update={"params": {"cache": {"batch_size": 64},
                                                         "pretrain_frames": 22}})),
                      store, settings).quality
    assert trained["verdict"] == "ok", trained


def test_the_reference_is_rendered_once_and_reused(env):
    settings, store = env
    first = execute(RenderJob.parse(SPEC), store, settings)
    second = execute(RenderJob.parse(SPEC.model_copy(update={"seeds": 2})), store, settings)
    assert first.reference["rendered_now"] and not second.reference["rendered_now"]
    assert first.reference["key"] == second.reference["key"]
    assert len(list(settings.references_dir.glob("*.variance.exr"))) == 1


def test_a_method_that_does_not_apply_is_refused_before_its_reference(env):
    """grid-cache holds diffuse radiance only: on the glossy Cornell box it is refused
    from the scene's features, before a reference (minutes at a real spp) is rendered."""
    settings, store = env
    spec = SPEC.model_copy(update={"scene": "cornell-glossy", "method": "grid-cache"})
    with pytest.raises(methods.NotApplicable, match="glossy"):
        execute(RenderJob.parse(spec), store, settings)
    assert not list(settings.references_dir.glob("*.exr"))


def test_a_damaged_reference_file_is_rendered_again(env):
    settings, store = env
    first = execute(RenderJob.parse(SPEC), store, settings)
    (settings.references_dir / f"{first.reference['key']}.exr").write_bytes(b"not an exr")
    again = execute(RenderJob.parse(SPEC), store, settings)
    assert again.reference["rendered_now"]


def test_nonfinite_pixels_are_counted_and_fail_the_quality_flag(env, monkeypatch):
    settings, store = env
    original = methods.METHODS["pt"]

    def render_with_a_nan(*args, **kwargs):
        output = original.render(*args, **kwargs)
        output.accumulated[0, 0, 1] = np.nan
        return output

    monkeypatch.setitem(methods.METHODS, "pt",
                        dataclasses.replace(original, render=render_with_a_nan))
    summary = execute(RenderJob.parse(SPEC.model_copy(update={"resolution": 16})), store, settings)
    # 1 of 256 pixels per seed: below the 1 % limit, so flagged but still scored.
    assert summary.quality["finite"] is False and summary.quality["nonfinite_pixels"] == 3
    assert summary.quality["verdict"] == "nonfinite" and summary.quality["withheld"] == []
    assert summary.quality["nonfinite_fraction"] == pytest.approx(1 / 256)
    assert "0.391 %" in summary.quality["reasons"][0]["message"]
    assert all(s["nonfinite_pixels"] == 1 for s in summary.per_seed)
    assert np.isfinite(summary.metrics["mrse_mean"])
    assert store.get_run(summary.run_id).quality["finite"] is False


def test_kept_frames_are_stored_per_seed(env):
    settings, store = env
    summary = execute(RenderJob.parse(SPEC.model_copy(update={"keep_frames": True, "seeds": 2})), store, settings)
    run = store.get_run(summary.run_id)
    frames = sorted((a.seed_result_id, a.kind) for a in run.artifacts if a.kind.startswith("frame"))
    assert len(frames) == 2 * SPEC.frames


def test_convergence_over_frames_is_stored_per_seed(env):
    settings, store = env
    summary = execute(RenderJob.parse(SPEC.model_copy(update={"frames": 4, "seeds": 2})), store, settings)
    run = store.get_run(summary.run_id)
    for seed in run.seed_results:
        curve = seed.metrics["convergence"]
        assert len(curve["frame_mrse"]) == len(curve["accumulated_mrse"]) == 4
        assert curve["frame_mrse"][0] == pytest.approx(curve["accumulated_mrse"][0])
        # The last accumulated error is the run's error of the accumulated image.
        assert curve["accumulated_mrse"][-1] == pytest.approx(seed.metrics["mrse"], rel=1e-5)
        # Averaging 4 independent 1-spp frames lowers the error (PT is unbiased).
        assert curve["accumulated_mrse"][-1] < np.mean(curve["frame_mrse"])


def test_a_time_budget_calibrates_spp_and_is_recorded(env):
    from jobs.protocol.spec import TimeBudget

    settings, store = env
    # What is recorded, not whether the machine is quiet: loaded probes count here.
    budget = TimeBudget(pt_spp=2, candidates=[1, 2, 4, 8], probe_frames=2, tolerance_ms=1e6,
                        allow_loaded=True)
    summary = execute(RenderJob.parse(SPEC.model_copy(update={"time_budget": budget, "seeds": 2})), store,
                      settings)
    calibration = summary.metrics["calibration"]
    assert calibration["knob"] == "spp" and calibration["fits"]
    # A huge tolerance: every candidate fits, so the largest is chosen and the run uses it.
    assert calibration["chosen"] == 8 and summary.spec.spp == 8
    assert set(calibration["measured_s"]) == {"1", "2", "4", "8"}
    assert calibration["budget_source"].startswith("PT 2 spp")
    assert store.get_run(summary.run_id).spp == 8

    tiny = TimeBudget(ms=1e-6, candidates=[1, 2], probe_frames=1, allow_loaded=True)
    over = execute(RenderJob.parse(SPEC.model_copy(update={"time_budget": tiny, "seeds": 2})), store, settings)
    assert over.metrics["calibration"]["fits"] is False and over.spec.spp == 1
    # spp's frame time grows with it: nothing above a candidate clearly over is timed.
    assert list(over.metrics["calibration"]["measured_s"]) == ["1"]
    assert list(over.metrics["calibration"]["not_timed"]) == ["2"]


def test_a_time_budget_needs_a_knob(env):
    from jobs.protocol.spec import TimeBudget

    settings, store = env
    spec = SPEC.model_copy(update={"method": "nrc", "time_budget": TimeBudget(ms=10)})
    with pytest.raises(methods.MethodError, match="no equal-time knob"):
        execute(RenderJob.parse(spec), store, settings)
    with pytest.raises(ValueError, match="exactly one"):
        TimeBudget(ms=1, pt_spp=2)


def test_path_histograms_average_over_the_union_of_the_seeds_bins():
    from jobs.protocol.executor import mean_over_seeds

    seeds = [{"avg_path_vertices": 2.0, "cache_depth_fractions": {"0": 0.5, "1": 0.5}},
             {"avg_path_vertices": 3.0, "cache_depth_fractions": {"0": 0.5, "2": 0.5}}]
    mean = mean_over_seeds(seeds)
    assert mean["avg_path_vertices"] == 2.5
    # A bin one seed never hit counts 0 there (it used to be dropped, or averaged
    # over the seeds that hit it only).
    assert mean["cache_depth_fractions"] == {"0": 0.5, "1": 0.25, "2": 0.25}


def test_per_cache_metrics_say_why_they_are_missing():
    from pathlib import Path

    from jobs.protocol.executor import PER_CACHE_KEYS, per_cache_metrics
    from jobs.protocol.references import LoadedReference
    from metrics.statistics import RunningMoments

    image = np.ones((2, 2, 3), np.float32)
    reference = LoadedReference(id=1, key="k", mean=image, variance=0 * image, spp=8,
                                flip_exposures=(0.0, 1.0), split_half={},
                                image_path=Path("r.exr"), rendered_now=False)
    one_frame = RunningMoments()
    one_frame.add(image)
    for moments, reason in (([], "no per-frame statistics"), ([one_frame], "at least 2 images, have 1")):
        result = per_cache_metrics(moments, reference, 0.01)
        assert all(result[key] is None for key in PER_CACHE_KEYS)
        assert reason in result["per_cache_unavailable"]


def test_every_registered_metric_is_stored_served_and_tabulated(env):
    """The registry drives the executor, the API row, the CLI tables and the sweep row:
    PSNR (one registry entry) appears in each without code of its own there. The run
    denoises (the denoised errors are registered too) and records the denoiser."""
    from jobs.sweeps.sweep import SweepResult, point_row
    from metrics.registry import LISTED, METRICS, PER_SEED, Aggregate
    from service.api.schemas import RunOut
    from service.tables import metric_label, sweep_table

    settings, store = env
    summary = execute(RenderJob.parse(SPEC.model_copy(update={"denoised": True})), store,
                      settings)
    run = store.get_run(summary.run_id)
    # V_rel needs a residual estimator (two-level methods, control variates): pt has none.
    computed = [m for m in METRICS if m.name != "v_rel"]
    assert "v_rel_mean" not in run.metrics
    for metric in computed:
        assert metric.key in run.metrics, metric.name
    for metric in (m for m in PER_SEED if m in computed):
        assert all(metric.seed_key in s.metrics for s in run.seed_results), metric.name
    seeds = [s.metrics["psnr"] for s in run.seed_results]
    assert all(0 < p < 100 for p in seeds)
    assert run.metrics["psnr_mean"] == pytest.approx(np.mean(seeds))
    # The denoiser's provenance: OIDN's version as the installed package ships it.
    assert run.metrics["denoiser"]["version"] == oidn_version
    assert run.versions["pyoidn"].startswith(oidn_version)
    assert run.params["spec"]["denoised"] is True
    assert all(s.metrics["denoised_frames"] == 2 for s in run.seed_results)
    assert run.metrics["denoiser"]["seeds_denoised"] == 3

    row = RunOut.of(run).model_dump()
    for metric in LISTED:
        assert row[metric.field] == run.metrics[metric.key], metric.name
    assert row["psnr"] == run.metrics["psnr_mean"] and row["flip"] == run.metrics["flip_hdr_mean"]

    console = Console(width=250, record=True)
    console.print(metrics_table(summary.result))
    text = console.export_text()
    for metric in METRICS:   # pt has no cache: no per-cache rows, no V_rel
        cached = metric.aggregate is not Aggregate.PER_CACHE and metric in computed
        assert (metric_label(metric) in text) == cached, metric.name
    assert f"Intel Open Image Denoise {oidn_version} (RT filter" in text
    assert "PSNR (dB, higher better)" in text and "MRSE (lower better)" in text
    sweep_row = point_row("nirc", 0.5, run)
    assert {m.field for m in LISTED} <= set(sweep_row.model_dump()) \
        and sweep_row.psnr == row["psnr"]
    result = SweepResult(sweep_id=1, key="k", kind="eps", scene="cornell-box", device_key="dev",
                         rows=[sweep_row], skipped=[], work=dict.fromkeys(
        ("reference_rendered", "snapshots_trained", "snapshots_reused", "points_rendered",
         "points_reused", "calibrations"), 0))
    console.print(sweep_table(result))
    text = console.export_text()
    assert all(metric.label in text for metric in LISTED) and "PSNR" in text


def _ar1_seeds(phi: float, truth: np.ndarray, sigma: float, frames: int, seeds: int,
               seed: int) -> list[RunningMoments]:
    """Each seed's frame moments of unbiased frames X_f = T (1 + sigma e_f), e_f a
    stationary AR(1) sequence with coefficient ``phi`` (unit variance) per pixel."""
    rng = np.random.default_rng(seed)
    result = []
    for _ in range(seeds):
        moments, e = RunningMoments(), rng.standard_normal(truth.shape)
        for _ in range(frames):
            moments.add(truth * (1.0 + sigma * e))
            e = phi * e + np.sqrt(1.0 - phi * phi) * rng.standard_normal(truth.shape)
        result.append(moments)
    return result


def test_per_cache_statistics_are_left_out_for_correlated_frames():
    """Unbiased frames: independent ones give per-cache rBias^2 ~ 0; AR(1) frames with
    phi 0.9 (what temporal reuse makes) give the variance the frames' spread misses as
    'bias', so a method that declares correlated frames gets none, with the reason."""
    truth = np.random.default_rng(1).uniform(0.2, 2.0, (24, 24, 3))
    reference = SimpleNamespace(mean=truth, variance=np.zeros_like(truth))
    sigma, frames, eps = 0.3, 32, 0.01
    independent = per_cache_metrics(_ar1_seeds(0.0, truth, sigma, frames, 8, 2), reference,
                                    eps)["rbias2_per_cache_mean"]
    correlated = per_cache_metrics(_ar1_seeds(0.9, truth, sigma, frames, 8, 3), reference,
                                   eps)["rbias2_per_cache_mean"]
    # E[(M - T)^2] = s2 c / F and E[S^2] = s2 (F - c) / (F - 1), c = 1 + 2 sum (1 - k/F) phi^k.
    lags = np.arange(1, frames)
    c = 1 + 2 * np.sum((1 - lags / frames) * 0.9**lags)
    weight = np.mean((sigma * truth) ** 2 / (truth**2 + eps))
    expected = weight * (c / frames - (frames - c) / (frames * (frames - 1)))
    print(f"per-cache rBias^2: independent {independent:.2e}, AR(1) {correlated:.4f}, "
          f"expected {expected:.4f}")
    assert abs(independent) < 0.05 * expected
    assert correlated == pytest.approx(expected, rel=0.25)
    left_out = per_cache_metrics(_ar1_seeds(0.9, truth, sigma, frames, 2, 4), reference, eps,
                                 correlated_frames=True)
    assert left_out["rbias2_per_cache_mean"] is None and left_out["rvar_per_cache"] is None
    assert "frames share samples" in left_out["per_cache_unavailable"]


def test_a_method_with_temporal_reuse_reports_no_per_cache_statistics(env):
    settings, store = env
    assert {n for n, m in methods.METHODS.items() if m.correlated_frames} == {
        "restir-di", "restir-nvc"}
    summary = execute(RenderJob.parse(SPEC.model_copy(update={"scene": "cornell-box", "method": "restir-di",
                                              "seeds": 2})), store, settings)
    assert summary.metrics["rbias2_per_cache_mean"] is None
    assert "temporal reuse" in summary.metrics["per_cache_unavailable"]
    assert summary.metrics["rbias2"] is not None


def test_a_scene_an_earlier_job_left_is_freed_before_the_next_job_renders(env, monkeypatch):
    """A scene of an earlier job of the process, held only by a reference cycle, would be
    freed by a garbage collection in the middle of the next job's frames, which makes
    every frozen function that walks the scenes record again (measured: nirc-nvc-env
    recorded 8 times after its warm-up once a freed pt job's scene went; docs/timing.md).
    The executor collects before it renders. Planted: without its collections the
    earlier scene is still alive when the next job renders."""
    import gc
    import weakref

    from jobs.protocol import executor

    class Scene:   # a weak-referenceable stand-in for the earlier job's scene
        pass

    alive: weakref.WeakValueDictionary = weakref.WeakValueDictionary()

    def leave_a_scene_in_a_cycle() -> None:
        left: dict = {"scene": Scene()}
        left["cycle"] = left
        alive["scene"] = left["scene"]

    seen_at_render: list[bool] = []
    real_render_seed = executor.render_seed

    def watching(*args, **kwargs):
        seen_at_render.append("scene" in alive)
        return real_render_seed(*args, **kwargs)

    settings, store = env
    monkeypatch.setattr(executor, "render_seed", watching)
    job = RenderJob.parse(SPEC.model_copy(update={"seeds": 1}))
    gc.disable()
    try:
        leave_a_scene_in_a_cycle()
        execute(job, store, settings)
        leave_a_scene_in_a_cycle()
        monkeypatch.setattr(executor.gc, "collect", lambda *args: 0)   # planted
        execute(job, store, settings)
    finally:
        gc.enable()
    assert seen_at_render == [False, True]


class _Scene:
    """A weak-referenceable stand-in for a job's Mitsuba scene."""


def test_the_collection_before_a_job_is_full_only_where_an_earlier_scene_outlived_its_job():
    """A full collection walks the whole heap (~0.1 s a job); it runs where the last job's
    scene is still held (here by a cycle frozen out of the collector's generations with
    it, which only a full collection frees) and every FULL_EVERY jobs; otherwise what the
    job made since the freeze is collected and the scene goes by its reference count.
    Planted: without the held-scene check the cycle outlives the collection."""
    import gc
    import weakref

    from jobs.protocol.executor import FULL_EVERY, JobCollector

    def job_leaving(collector: JobCollector, cycle: bool) -> weakref.ref:
        scene = _Scene()
        holder: dict = {"scene": scene}
        if cycle:
            holder["self"] = holder
        collector.after_load(scene)     # freezes the holder and the scene with the rest
        return weakref.ref(scene)

    try:
        collector = JobCollector()
        assert collector.before_job() is True             # the first: nothing frozen yet
        plain = job_leaving(collector, cycle=False)
        assert plain() is not None                        # kept for the next question
        assert collector.before_job() is False and plain() is None
        held = job_leaving(collector, cycle=True)
        assert collector.before_job() is True and held() is None
        for _ in range(FULL_EVERY - 1):
            job_leaving(collector, cycle=False)
            assert collector.before_job() is False
        job_leaving(collector, cycle=False)
        assert collector.before_job() is True              # the bound on other leftovers
        assert collector.full_collections == 2            # the first job's is not counted

        planted = JobCollector()
        planted.before_job()
        kept = job_leaving(planted, cycle=True)
        planted._scene = None                             # planted: nothing to ask about
        assert planted.before_job() is False and kept() is not None
    finally:
        gc.unfreeze()
        gc.collect()


def test_release_lets_go_of_the_last_jobs_scene_and_what_it_froze():
    """After release() neither the kept scene nor a scene held by a frozen cycle is alive,
    nothing stays frozen, and the next job collects in full (as the first). Planted: a
    release that only drops the kept scene leaves the frozen cycle's scene alive."""
    import gc
    import weakref

    from jobs.protocol.executor import JobCollector

    def job(collector: JobCollector) -> tuple[weakref.ref, weakref.ref]:
        collector.before_job()
        kept, cycled = _Scene(), _Scene()
        holder: dict = {"scene": cycled}
        holder["self"] = holder
        collector.after_load(kept)
        del holder
        return weakref.ref(kept), weakref.ref(cycled)

    try:
        collector = JobCollector()
        kept, cycled = job(collector)
        assert kept() is not None and cycled() is not None and gc.get_freeze_count() > 0
        collector.release()
        assert kept() is None and cycled() is None and gc.get_freeze_count() == 0
        assert collector.before_job() is True

        planted = JobCollector()
        kept, cycled = job(planted)
        planted._scene = None                   # planted: the scene dropped, nothing collected
        assert kept() is None and cycled() is not None
    finally:
        gc.unfreeze()
        gc.collect()


def test_seeds_that_train_caches_report_the_mean_of_their_caches_rbias2():
    """Four caches biased +-15 % in turn (opposite biases): pooled, rBias^2 cancels to
    about -b^2/(K-1); for seeds whose method_stats name a cache the headline is the
    caches' mean with its t interval, above 0 (planted: the same seeds without a cache
    keep the pooled value, which the interval calls within noise)."""
    rng = np.random.default_rng(5)
    truth = rng.uniform(0.2, 2.0, (12, 12, 3))
    reference = SimpleNamespace(mean=truth, variance=np.zeros_like(truth))
    moments = []
    for sign in (1, -1, 1, -1):
        seed_moments = RunningMoments()
        for _ in range(8):
            seed_moments.add(truth * (1 + 0.15 * sign + 0.1 * rng.standard_normal(truth.shape)))
        moments.append(seed_moments)
    images = [m.estimate().mean for m in moments]
    per_seed = [{"mrse": 0.1, "method_stats": {"caches": {"cache": {}}}} for _ in images]

    cached = aggregate(per_seed, images, reference, 0.01, 0.1, moments)
    plain = aggregate([{"mrse": 0.1, "method_stats": {}} for _ in images], images, reference,
                      0.01, 0.1, moments)
    true_rbias2 = float(np.mean((0.15 * truth) ** 2 / (truth ** 2 + 0.01)))
    assert cached["rbias2_basis"] == "per cache" and plain["rbias2_basis"] == "pooled"
    assert cached["rbias2"] == pytest.approx(true_rbias2, rel=0.1)
    assert cached["rbias2_ci95"][0] > 0 and cached["rbias2_seed_values"] == \
        cached["rbias2_per_cache"]
    assert plain["rbias2"] == plain["rbias2_pooled"] == cached["rbias2_pooled"]
    assert plain["rbias2"] < 0.1 * true_rbias2 and plain["rbias2_ci95"][0] <= 0
    assert "chi-square" in cached["rvar_ci_note"] and "jackknife" in plain["rvar_ci_note"]
