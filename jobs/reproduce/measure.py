"""Our numbers for a figure: the generic parameter sweep's stored points (a point
already stored under its key is read back, not rendered again) and their estimates with
95 % intervals."""

from __future__ import annotations

from typing import Any

from jobs.reproduce.registry import Budget, Context
from jobs.reproduce.results import Estimate

#: The most pre-fill passes (the method's default limit).
PREFILL_FRAMES = 128

MSE_NOTE = ("MSE at N samples per pixel (relative, as MRSE): rBias² + rVar₁ / N, rVar₁ the "
            "variance of one one-spp frame; its interval adds the ends of the two 95 % "
            "intervals (at least 90 % coverage)")
SAMPLE_VARIANCE_NOTE = ("rVar₁: the relative variance of one frame about its own cache's "
                        "mean (each seed's F frames), the mean over the K seeds; 95 % "
                        "interval: Student t (K-1 degrees of freedom) over the seeds")
LENGTH_NOTE = ("path length: the paper's (vertices up to the termination vertex, a blended "
               "segment by its weight); 95 % interval: Student t (K-1 degrees of freedom) "
               "over the K renders' means")


def grid_params(ctx: Context, policy: str, policy_params: dict[str, Any],
                **extra: Any) -> dict[str, Any]:
    """`grid-cache` parameters with ``policy`` and the budget's grid preset."""
    return {"termination": policy, "termination_params": policy_params,
            "cache": {"preset": ctx.budget.grid_preset}, "prefill_frames": PREFILL_FRAMES,
            **extra}


def sweep(ctx: Context, scene: str, method: str, parameter: str, values: list[Any],
          params: dict[str, Any], max_depth: int = -1,
          denoised: bool = False) -> list[tuple[Any, Any]]:
    """(sweep row, stored run) of ``method`` on ``scene`` at every value of ``parameter``
    (a dotted name), at the context's budget; ``denoised``: each point also scored after
    the denoiser (metrics/denoised.py)."""
    from jobs.protocol.spec import ParameterSweep, ReferenceSpec, SweepSpec
    from jobs.sweeps.sweep import run_sweep

    b = ctx.budget
    spec = SweepSpec(scene=scene, methods=[method], resolution=b.resolution, seeds=b.seeds,
                     frames=b.frames, max_depth=max_depth,
                     reference=ReferenceSpec(spp=b.ref_spp),
                     parameter=ParameterSweep(name=parameter, values=values), params=params,
                     denoised=denoised)
    # The figure draws its own plot from the rows: none of the sweep's.
    result = run_sweep(spec, ctx.store, ctx.settings, progress=ctx.progress, plots=False)
    for name in ("points_rendered", "points_reused"):
        ctx.work[name] = ctx.work.get(name, 0) + result.work.get(name, 0)
    return [(row, ctx.store.get_run(row.id)) for row in result.rows]


def metric(row: Any, field: str, scale: float = 1.0) -> Estimate:
    """A row's metric ``field`` (rvar, rbias2, mrse) times ``scale``, with its interval."""
    value, interval = getattr(row, field), getattr(row, f"{field}_ci95")
    return Estimate(value=None if value is None else scale * value,
                    ci95=None if interval is None else [scale * v for v in interval],
                    note=f"{field}: {getattr(row, f'{field}_ci_note')}")


def frame_ms(row: Any) -> Estimate:
    """A row's median frame in milliseconds (no interval: one median)."""
    seconds = row.seconds_per_frame
    return Estimate(value=None if seconds is None else 1e3 * seconds)


def sample_variance(run: Any, scale: float = 1.0) -> Estimate:
    """rVar₁ (:data:`SAMPLE_VARIANCE_NOTE`) times ``scale``: what averaging N frames with
    one cache divides by N, unlike the seeds' spread of the render (``rvar``), which
    also holds the caches' differences. For the path tracer the two agree."""
    from metrics.bias_intervals import bias_interval

    per_seed = (run.metrics or {}).get("rvar_per_cache")
    if not per_seed:
        return Estimate(value=None, note=(run.metrics or {}).get("per_cache_unavailable"))
    interval, note = bias_interval(per_seed, SAMPLE_VARIANCE_NOTE)
    mean = sum(per_seed) / len(per_seed)
    return Estimate(value=scale * mean, note=note,
                    ci95=None if interval is None else [scale * v for v in interval])


def mse_at(row: Any, run: Any, samples: float) -> Estimate:
    """The relative MSE of an N-sample estimate (:data:`MSE_NOTE`): the cache's squared
    bias does not shrink with N, the variance of one sample does ([VTT24] Eq. 4 over N
    samples). rBias² is the caches' own (per cache) for `grid-cache`."""
    bias2, var = metric(row, "rbias2"), sample_variance(run, 1.0 / samples)
    if bias2.value is None or var.value is None:
        return Estimate(value=None, note=MSE_NOTE)
    interval = (None if bias2.ci95 is None or var.ci95 is None else
                [bias2.ci95[0] + var.ci95[0], bias2.ci95[1] + var.ci95[1]])
    return Estimate(value=bias2.value + var.value, ci95=interval, note=MSE_NOTE)


def path_length(run: Any) -> Estimate:
    """The paper's path length (``weighted_length``; ``avg_path_vertices`` for a method
    without a cache), the mean over the K renders with its interval over them."""
    from metrics.bias_intervals import bias_interval

    def length(stats: dict[str, Any]) -> float:
        return float(stats.get("weighted_length", stats.get("avg_path_vertices", "nan")))

    per_seed = [length(seed.metrics.get("path_stats") or {}) for seed in run.seed_results]
    interval, note = bias_interval(per_seed, LENGTH_NOTE)
    return Estimate(value=length(run.path_stats or {}), ci95=interval, note=note)


def kernel_ms(row: Any, stage: str) -> Estimate:
    """Kernel milliseconds of the median frame's ``stage`` (no interval: one median)."""
    parts = row.kernel_breakdown_ms or {}
    return Estimate(value=parts.get(stage))


def grid_presets(run: Any) -> set[str]:
    """The grid presets a `grid-cache` run's caches started from, as each seed's render
    states it (empty: another method)."""
    caches = (((seed.metrics.get("method_stats") or {}).get("caches") or {}).get("cache")
              for seed in run.seed_results)
    return {str(cache["preset"]) for cache in caches if cache and "preset" in cache}


def budget_settings(ctx: Context, **extra: Any) -> dict[str, Any]:
    """The settings line of a figure's table."""
    b = ctx.budget
    return {"resolution": f"{b.resolution}x{b.resolution}", "seeds K": b.seeds,
            "frames F": b.frames, "reference spp": b.ref_spp, "grid preset": b.grid_preset,
            "why": b.why, **extra}


QUICK_WHY = ("--quick: 32x32 with the CPU preset; the paper's grid costs about 8x as much per "
             "propagation pass, which is most of a frame whatever the image size (measured "
             "on door at 32x32: 0.7 s a pass, 100 s per point of K = 4 on the loaded 2-core "
             "machine), so a figure with it takes tens of minutes")
FULL_WHY = ("--full: 64x64 with the paper's grid, the largest size it is run at here (its "
            "propagation pass's cost)")


def quick_budget(values: tuple[float, ...] = ()) -> Budget:
    """A figure's ``quick`` budget: minutes on 2 cores (:data:`QUICK_WHY`)."""
    return Budget(resolution=32, seeds=4, frames=4, ref_spp=1024, grid_preset="cpu",
                  why=QUICK_WHY, values=values)


def full_budget(values: tuple[float, ...] = ()) -> Budget:
    """A figure's ``full`` budget: the paper's grid (:data:`FULL_WHY`)."""
    return Budget(resolution=64, seeds=8, frames=8, ref_spp=4096, grid_preset="paper",
                  why=FULL_WHY, values=values)
