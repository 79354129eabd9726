"""[VTT24] Fig. 10: equal samples, PT, variance bounding (t = 1), MSE minimization
(s = 100) and area-spread (c = 0.01), at 1 spp and after denoising four accumulated
frames.

Ours: `grid-cache` with each policy (var-bound's t relative to the pixel's brightness,
as the paper's thresholds are; the budget's grid preset) and `pt` on `cornell-box`
(for the paper's Bunny), `door` and `corridor`; each point a parameter sweep's stored
run with the denoised errors (metrics/denoised.py): Intel Open Image Denoise stands in
for the paper's SVGF (a temporal filter in the renderer's own pipeline), each seed's
1-spp frames denoised alone and the mean of its four frames denoised. Per point the
mean over the K seeds with a Student-t interval over them, and where paths end in the
cache: the share of paths that end at the primary hit (``cache_depth`` 1, the paper's
"terminates at a primary hit") and at the second vertex."""

from __future__ import annotations

import math
import statistics
from pathlib import Path
from typing import Any

from jobs.reproduce.measure import (
    budget_settings,
    full_budget,
    grid_params,
    grid_presets,
    path_length,
    quick_budget,
    sweep,
)
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Context, FigureSpec, register
from jobs.reproduce.results import Estimate, Point, Reproduction, Verdict

#: Our scenes, and the paper's they stand for.
SCENES = {"cornell-box": "Bunny", "door": "Door", "corridor": "Corridor"}
AREA_SPREAD = "area-spread c = 0.01"
#: (series, method, swept parameter, value, the policy's other parameters or None for PT)
POLICIES: tuple[tuple[str, str, str, float, tuple[str, dict[str, Any]] | None], ...] = (
    ("PT (survival 90 %)", "pt", "rr_survival", 0.9, None),
    ("var-bound t = 1", "grid-cache", "termination_params.threshold", 1.0,
     ("var-bound", {"relative": True})),
    ("mse-min s = 100", "grid-cache", "termination_params.samples", 100.0, ("mse-min", {})),
    (AREA_SPREAD, "grid-cache", "termination_params.c", 0.01, ("area-spread", {})),
)
X_LABEL = "policy, in the legend's order"
QUANTITIES = {"mrse_frame": "MRSE, 1 spp", "denoised_mrse_frame": "OIDN MRSE, 1 frame",
              "denoised_mrse_accum": "OIDN MRSE, 4 frames",
              "denoised_flip_accum": "OIDN FLIP, 4 frames",
              "path_length": "path length (vertices)",
              "primary_pct": "% paths ending at the primary hit",
              "second_pct": "% paths ending at the second vertex"}
SEED_NOTE = ("MRSE and FLIP: the mean over the K seeds (a seed's 1-spp value: the mean over "
             "its frames); 95 % interval: log scale (delta method), Student t with K-1 "
             "degrees of freedom over the seeds")
SVGF_NOTE = ("Intel Open Image Denoise (still images, albedo and normal features) stands in "
             "for the paper's SVGF, a temporal filter that needs the renderer's own pipeline "
             "(docs/metrics.md, 'Denoised error')")

QUICK = quick_budget()
FULL = full_budget()


def over_seeds(run: Any, value_of: Any) -> Estimate:
    """The mean over the run's seeds of ``value_of(seed metrics)`` (None: left out), a
    positive error, with its 95 % interval on the log scale over them (:data:`SEED_NOTE`)."""
    from metrics.statistics import log_scale_interval

    values = [v for seed in run.seed_results
              if (v := value_of(seed.metrics or {})) is not None]
    if not values:
        return Estimate(value=None, note=SEED_NOTE)
    mean = sum(values) / len(values)
    if len(values) < 2 or not mean > 0:
        return Estimate(value=mean, note=f"{SEED_NOTE} (none: {len(values)} seeds, mean "
                                         f"{mean:.3g})")
    interval = log_scale_interval(mean, statistics.stdev(values) / math.sqrt(len(values)),
                                  len(values) - 1)
    return Estimate(value=mean, ci95=list(interval), note=SEED_NOTE)


def _mean_frame_mrse(metrics: dict[str, Any]) -> float | None:
    frames = (metrics.get("convergence") or {}).get("frame_mrse") or []
    return None if not frames or None in frames else sum(frames) / len(frames)


def ending_pct(run: Any, vertex: int) -> Estimate:
    """The % of paths that end in the cache at ``vertex`` (1: the primary hit) over the
    run's frames (path statistics' ``cache_depth_fractions``; none for PT)."""
    fractions = (run.path_stats or {}).get("cache_depth_fractions")
    if not fractions:
        return Estimate(value=None, note="PT: no cache, paths end by roulette")
    return Estimate(value=100.0 * fractions.get(str(vertex), 0.0))


def values_of(run: Any) -> dict[str, Estimate]:
    """A denoised run's quantities (:data:`QUANTITIES`)."""
    return {"mrse_frame": over_seeds(run, _mean_frame_mrse),
            **{key: over_seeds(run, lambda m, key=key: m.get(key))
               for key in ("denoised_mrse_frame", "denoised_mrse_accum", "denoised_flip_accum")},
            "path_length": path_length(run), "primary_pct": ending_pct(run, 1),
            "second_pct": ending_pct(run, 2)}


def policy_run(ctx: Context, scene: str, policy: tuple[Any, ...]) -> tuple[Any, Any]:
    """(sweep row, stored run) of one policy on ``scene``, denoised."""
    _series, method, parameter, value, termination = policy
    params = {} if termination is None else grid_params(ctx, *termination)
    [(row, run)] = sweep(ctx, scene, method, parameter, [value], params, denoised=True)
    return row, run


def measure(ctx: Context) -> Reproduction:
    points: list[Point] = []
    presets: set[str] = set()
    for scene in SCENES:
        for index, policy in enumerate(POLICIES):
            row, run = policy_run(ctx, scene, policy)
            presets |= grid_presets(run)
            points.append(Point(scene=scene, series=policy[0], x=float(index), run_id=row.id,
                                values=values_of(run)))
    return Reproduction(
        paper="vt", figure="fig10", title="[VTT24] Fig. 10: equal samples, 1 spp and denoised",
        mode="", settings=budget_settings(ctx, **{"runs' grid presets": sorted(presets)}),
        x_label=X_LABEL, quantities=QUANTITIES, points=points, verdicts=verdicts(points),
        notes=[f"{ours} stands in for the paper's {theirs}" for ours, theirs in SCENES.items()
               if ours != theirs.lower()]
        + [SVGF_NOTE, "var-bound's t is relative to the pixel's brightness",
           "relative errors (MRSE, docs/metrics.md); HDR-FLIP at the reference's exposures"])


def verdicts(points: list[Point]) -> list[Verdict]:
    """Area-spread never ends a path at the primary hit (0 % on every scene) and mostly
    ends it early, at the second vertex (over half of its paths on every scene)."""
    spread = [p for p in points if p.series == AREA_SPREAD]
    detail = "; ".join(f"{p.scene}: {p.values['primary_pct'].text()} % at the primary hit, "
                       f"{p.values['second_pct'].text()} % at the second vertex" for p in spread)
    primary = [p.values["primary_pct"].value for p in spread]
    second = [p.values["second_pct"].value for p in spread]
    if not spread or None in primary or None in second:
        verdict = "not comparable"
    elif all(v == 0.0 for v in primary) and all(v > 50.0 for v in second):
        verdict = "holds"
    elif any(v > 0.0 for v in primary):
        verdict = "does not hold"
    else:
        verdict = "not comparable"
    return [Verdict(claim="area-spread never ends at a primary hit, then mostly ends early",
                    verdict=verdict,
                    reason=f"{detail or 'no area-spread points'} (the corners the paper "
                           "excepts are not measured)")]


def draw(reproduction: Reproduction, path: Path) -> Path:
    panels = [Panel(key, f"{scene}: {QUANTITIES[key]}", scene=scene) for scene in SCENES
              for key in ("mrse_frame", "denoised_mrse_accum")]
    return plot_panels(reproduction, panels, path, log_x=False)


FIGURE = register(FigureSpec("vt", "fig10", "equal samples on cornell-box, door and corridor: "
                             "PT, var-bound t = 1, mse-min s = 100 and area-spread c = 0.01 at "
                             "1 spp and after OIDN (for SVGF) of four frames",
                             {"quick": QUICK, "full": FULL}, measure, draw))
