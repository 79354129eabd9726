"""[VTT24] Fig. 7: variance bounding on the Veach door for Russian-roulette survival
100 %, 60 % and 20 %: variance, squared bias and MSE against the (absolute) variance
threshold t (left in the paper), and path length against t (right).

Ours: `grid-cache` with `var-bound` (absolute t) on `door`, the paper's grid preset, the
roulette's survival from the fifth vertex (the method's ``rr_depth``), paths at most
:data:`MAX_DEPTH` segments long (at 100 % survival only the limit ends a path that
stays in the closed room), the reference alike. Relative figures (docs/metrics.md), per
one-spp frame so that they read as the paper's one-sample quantities: rVar₁ (one
frame's variance about its cache's mean) and rBias² (the caches' own); the MSE of an
image of :data:`MSE_SAMPLES` samples is rBias² + rVar₁ / N (jobs/reproduce/measure.py)."""

from __future__ import annotations

from pathlib import Path

from jobs.reproduce.measure import (
    budget_settings,
    full_budget,
    grid_params,
    grid_presets,
    metric,
    mse_at,
    path_length,
    quick_budget,
    sample_variance,
    sweep,
)
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Context, FigureSpec, register
from jobs.reproduce.results import Point, Reproduction

SCENE = "door"
#: The paper's roulette survival probabilities.
SURVIVALS = (1.0, 0.6, 0.2)
#: Longest path in segments, renders and reference alike (module doc).
MAX_DEPTH = 16
#: The sample count of the MSE panel: the caption's MSE is that of an accumulated image
#: ("images not being completely converged" at low survival and high t), whose sample
#: count the paper does not state; this one is ours.
MSE_SAMPLES = 1000
QUANTITIES = {"rvar": "rVar₁ (one sample)", "rbias2": "rBias²",
              "mse": f"MSE at N = {MSE_SAMPLES} samples", "path_length": "path length (vertices)"}

QUICK = quick_budget((0.01, 0.1, 1.0, 10.0))
FULL = full_budget((0.001, 0.01, 0.1, 1.0, 10.0, 100.0))


def measure(ctx: Context) -> Reproduction:
    points: list[Point] = []
    presets: set[str] = set()
    for survival in SURVIVALS:
        series = f"survival {survival:.0%}"
        for row, run in sweep(ctx, SCENE, "grid-cache", "termination_params.threshold",
                              list(ctx.budget.values),
                              grid_params(ctx, "var-bound", {"relative": False},
                                          rr_survival=survival),
                              max_depth=MAX_DEPTH):
            presets |= grid_presets(run)
            points.append(Point(scene=SCENE, series=series, x=float(row.value), run_id=row.id,
                                values={"rvar": sample_variance(run),
                                        "rbias2": metric(row, "rbias2"),
                                        "mse": mse_at(row, run, MSE_SAMPLES),
                                        "path_length": path_length(run)}))
    return Reproduction(
        paper="vt", figure="fig7", title="[VTT24] Fig. 7: variance bounding on door",
        mode="", settings=budget_settings(ctx, **{"max depth": MAX_DEPTH,
                                                  "runs' grid presets": sorted(presets)}),
        x_label="variance threshold t (absolute)", quantities=QUANTITIES, points=points,
        notes=["our door is the project's built-in scene, not the paper's model",
               "relative figures (divided by the reference's squared value + 0.01); the "
               "paper plots absolute ones, so our y values are on another scale: compare "
               "shapes, not numbers",
               f"the MSE panel is an image of N = {MSE_SAMPLES} samples, our choice: the "
               "paper's caption speaks of converging images without stating N"])


def draw(reproduction: Reproduction, path: Path) -> Path:
    return plot_panels(reproduction, [Panel(key, label, log_y=key != "path_length")
                                      for key, label in QUANTITIES.items()], path)


FIGURE = register(FigureSpec("vt", "fig7", "variance bounding on door for roulette survival "
                             "100/60/20 %: variance, bias, MSE and path length against t",
                             {"quick": QUICK, "full": FULL}, measure, draw))
