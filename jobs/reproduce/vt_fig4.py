"""[VTT24] Fig. 4: the discrete test case of variance bounding, the MSE of the
one-sample estimator against the variance threshold t on a sampling tree.

Ours: the project's tree (renderers/termination_model.py, :func:`binary_tree` of depth
:data:`DEPTH`, exact caches; the paper only draws its own), every path enumerated, so
each number is an exact moment and needs no interval. With exact caches the estimator is
unbiased and its MSE is its variance, E[sum of the prefixed local variances] (Eq. 2);
variance bounding keeps it at t (Sec. 4.2, the blend of Eq. 5) until paths reach the
leaves, then it detaches and converges to the path tracer's variance."""

from __future__ import annotations

import math
from pathlib import Path

from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Budget, Context, FigureSpec, register
from jobs.reproduce.results import Estimate, Point, Reproduction, Verdict
from renderers.termination_model import (
    LEFT_PROBABILITY,
    Blend,
    Evaluation,
    binary_tree,
    blend,
    evaluate,
    variance_bounding,
)

#: Levels below the root of the tree (16 paths).
DEPTH = 4
VAR_BOUND, THRESHOLD, PATH_TRACER = "var-bound", "threshold (MSE = t)", "path tracer"
QUANTITIES = {"mse": "MSE (one sample)", "path_length": "mean path length (vertices)"}
#: How close an exact MSE must be to t to "follow" it (rounding only: the moments are exact).
FOLLOWS = 1e-9
#: Below this fraction of t the MSE has "detached" from the threshold.
DETACHED = 0.5

WHY = ("no scene: exact moments of a depth-4 tree by enumerating its 16 paths (about a "
       "second); --full only samples t more densely")
QUICK = Budget(resolution=0, seeds=0, frames=0, ref_spp=0, grid_preset="—", why=WHY,
               values=tuple(10.0 ** (k / 4) for k in range(-8, 20)))        # 0.01 .. 5.6e4
FULL = Budget(resolution=0, seeds=0, frames=0, ref_spp=0, grid_preset="—", why=WHY,
              values=tuple(10.0 ** (k / 16) for k in range(-32, 80)))


def _point(series: str, threshold: float, result: Evaluation) -> Point:
    return Point(scene="tree", series=series, x=threshold,
                 values={"mse": Estimate(value=result.mse()),
                         "path_length": Estimate(value=result.mean_length)})


def curve(thresholds: tuple[float, ...], blend: Blend = blend) -> list[Point]:
    """Variance bounding at every threshold, the line MSE = t, and the path tracer (no
    path cut) for the ceiling; ``blend`` is Eq. 5's, replaceable to plant a wrong one."""
    tree = binary_tree(DEPTH)
    path_tracer = evaluate(tree, lambda state: 1.0)
    points = [_point(VAR_BOUND, t, evaluate(tree, variance_bounding(t), blend))
              for t in thresholds]
    points += [Point(scene="tree", series=THRESHOLD, x=t, values={"mse": Estimate(value=t)})
               for t in thresholds]
    points += [_point(PATH_TRACER, t, path_tracer) for t in thresholds]
    return points


def _line(points: list[Point], series: str) -> list[tuple[float, float]]:
    return sorted((p.x, p.values["mse"].value) for p in points if p.series == series
                  and p.x is not None and p.values["mse"].value is not None)


def verdicts(points: list[Point]) -> list[Verdict]:
    """Claim 1: the MSE equals t at the smallest thresholds (a leading run of points);
    claim 2: at the largest it is below :data:`DETACHED` t and has stopped growing
    (the last two points equal) at the path tracer's variance."""
    line = _line(points, VAR_BOUND)
    ceiling = _line(points, PATH_TRACER)
    follows = [math.isclose(mse, t, rel_tol=FOLLOWS) for t, mse in line]
    leading = next((i for i, f in enumerate(follows) if not f), len(follows))
    first = (f"MSE = t at the {leading} smallest of {len(line)} thresholds"
             + (f", up to t = {line[leading - 1][0]:.3g}" if leading else "")
             + (f"; MSE {line[leading][1]:.4g} at t = {line[leading][0]:.3g}"
                if leading < len(line) else ""))
    claims = [Verdict(claim="the MSE initially follows the threshold",
                      verdict="holds" if leading >= 2 else "does not hold", reason=first)]
    (t_end, mse_end), (_, mse_before) = line[-1], line[-2]
    pt = ceiling[-1][1] if ceiling else math.nan
    detached = mse_end < DETACHED * t_end
    converged = math.isclose(mse_end, mse_before, rel_tol=FOLLOWS) and math.isclose(
        mse_end, pt, rel_tol=FOLLOWS)
    second = (f"at t = {t_end:.3g} the MSE is {mse_end:.4g} ({mse_end / t_end:.2g} t), "
              f"{'equal to' if converged else 'not yet'} the path tracer's {pt:.4g}")
    claims.append(Verdict(claim="the variance detaches and converges to a maximum",
                          verdict="holds" if detached and converged else "does not hold",
                          reason=second))
    return claims


def measure(ctx: Context) -> Reproduction:
    points = curve(ctx.budget.values)
    return Reproduction(
        paper="vt", figure="fig4", title="[VTT24] Fig. 4: variance bounding on a sampling tree",
        mode="", settings={"tree": f"binary, depth {DEPTH}, left chosen with "
                                   f"p = {LEFT_PROBABILITY}, exact caches",
                           "thresholds": len(ctx.budget.values), "why": ctx.budget.why},
        x_label="variance threshold t", quantities=QUANTITIES, points=points,
        verdicts=verdicts(points),
        notes=["the paper only draws its tree; ours is renderers/termination_model.py's "
               "(docs/variance_trading.md, 'The discrete model')",
               "exact moments (every path enumerated): no intervals",
               "exact caches: no bias, so the MSE is the variance"])


def draw(reproduction: Reproduction, path: Path) -> Path:
    return plot_panels(reproduction, [Panel("mse", "MSE against t"),
                                      Panel("path_length", "path length", log_y=False)], path)


FIGURE = register(FigureSpec("vt", "fig4", "discrete test case of variance bounding: MSE "
                             "and path length against the threshold t on a sampling tree",
                             {"quick": QUICK, "full": FULL}, measure, draw))
