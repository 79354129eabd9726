"""[VTT24] Fig. 5: the discrete test case of MSE minimization with biased inner caches,
the MSE against the sample count N, one line per sample target s (its marker at N = s),
with the exhaustive optimum.

Ours: the project's tree (renderers/termination_model.py, :func:`binary_tree` of depth
:data:`DEPTH` with the inner caches' biases :data:`EXAMPLE_BIASES`; the paper only draws
its own), every path enumerated, so each number is an exact moment and needs no
interval. A target's line is the greedy rule :class:`MSEMinimizing` (Sec. 4.3, this
project's margin and clamp) for that s, its MSE at N samples V / N + Bias² (Eq. 4); the
optimum at N is the least such MSE over all 677 sets of termination decisions."""

from __future__ import annotations

from collections.abc import Callable
from functools import cache
from pathlib import Path

from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Budget, Context, FigureSpec, register
from jobs.reproduce.results import Estimate, Point, Reproduction, Verdict
from jobs.reproduce.vt_fig9 import SAMPLE_COUNTS, at_target
from renderers.termination_model import (
    EXAMPLE_BIASES,
    Evaluation,
    MSEMinimizing,
    Node,
    Rule,
    binary_tree,
    evaluate,
    optimal_frontier,
)

DEPTH = 4
OPTIMUM = "exhaustive optimum"
QUANTITIES = {"mse": "MSE at N samples", "variance": "variance (one sample)",
              "bias2": "Bias²"}
#: Above this ratio to the optimum a target's decisions are "not optimal" (rounding only).
OPTIMAL = 1.0 + 1e-9

WHY = ("no scene: exact moments of a depth-4 tree and an exhaustive search over its 677 "
       "sets of decisions per sample count (about a second); --full adds the target 10^5")
QUICK = Budget(resolution=0, seeds=0, frames=0, ref_spp=0, grid_preset="—", why=WHY,
               values=(1.0, 10.0, 100.0, 1000.0, 10000.0))
FULL = Budget(resolution=0, seeds=0, frames=0, ref_spp=0, grid_preset="—", why=WHY,
              values=(1.0, 10.0, 100.0, 1000.0, 10000.0, 100000.0))


def _point(series: str, samples: float, result: Evaluation) -> Point:
    return Point(scene="tree", series=series, x=samples,
                 values={"mse": Estimate(value=result.mse(samples)),
                         "variance": Estimate(value=result.variance),
                         "bias2": Estimate(value=result.bias ** 2)})


def tree() -> Node:
    return binary_tree(DEPTH, biases=EXAMPLE_BIASES)


@cache
def optimum(samples: float) -> Evaluation:
    """The least MSE at ``samples`` over every set of decisions (searched once per N)."""
    return optimal_frontier(tree(), samples)[1]


def lines(targets: tuple[float, ...],
          rule_for: Callable[[float], Rule] = MSEMinimizing) -> list[Point]:
    """Each target's rule (``rule_for(s)``, replaceable to plant another) at every sample
    count of :data:`SAMPLE_COUNTS` and the targets, and the optimum at each of them."""
    counts = sorted({*SAMPLE_COUNTS, *targets})
    points = []
    for target in targets:
        result = evaluate(tree(), rule_for(target))
        points += [_point(f"mse-min s = {target:g}", n, result) for n in counts]
    points += [_point(OPTIMUM, n, optimum(n)) for n in counts]
    return points


def verdicts(points: list[Point]) -> list[Verdict]:
    """At each target s: the rule's MSE at N = s against the optimum's there, and which
    has more variance. Holds: not optimal at half the targets or more ('often'), and at
    most of those with more variance than the optimum (it switched too early); does not
    hold: optimal everywhere, or never more variance where it is not."""
    optimum = {p.x: p for p in points if p.series == OPTIMUM}
    worse, early, detail = [], [], []
    targets = [p for p in points if at_target(p)]
    for point in targets:
        best = optimum[point.x]
        ratio = point.values["mse"].value / best.values["mse"].value
        more = point.values["variance"].value > best.values["variance"].value * OPTIMAL
        detail.append(f"s = {point.x:g}: {ratio:.2f}x the optimum"
                      + ("" if ratio <= OPTIMAL else
                         f", variance {point.values['variance'].value:.3g} against "
                         f"{best.values['variance'].value:.3g}"))
        if ratio > OPTIMAL:
            worse.append(point.x)
            early += [point.x] if more else []
    reason = (f"not optimal at {len(worse)} of {len(targets)} targets, with more variance "
              f"than the optimum at {len(early)} of them; " + "; ".join(detail))
    if not worse or not early:
        verdict = "does not hold"
    elif 2 * len(worse) >= len(targets) and 2 * len(early) > len(worse):
        verdict = "holds"
    else:
        verdict = "not comparable"
    return [Verdict(claim="decisions not optimal, switching to more variance too early",
                    verdict=verdict, reason=reason)]


def measure(ctx: Context) -> Reproduction:
    points = lines(ctx.budget.values)
    return Reproduction(
        paper="vt", figure="fig5", title="[VTT24] Fig. 5: MSE minimization on a sampling tree "
                                         "with biased caches",
        mode="", settings={"tree": f"binary, depth {DEPTH}, biased inner caches "
                                   "(EXAMPLE_BIASES)",
                           "margin": MSEMinimizing.margin, "clamp": MSEMinimizing.clamp,
                           "targets s": [f"{s:g}" for s in ctx.budget.values],
                           "why": ctx.budget.why},
        x_label="sample count N", quantities=QUANTITIES, points=points,
        verdicts=verdicts(points),
        notes=["the paper only draws its tree; ours is renderers/termination_model.py's "
               "(docs/variance_trading.md, 'The discrete model')",
               "exact moments (every path enumerated): no intervals",
               "each line's enlarged marker is its own target N = s; the optimum is "
               "searched anew at every N",
               "margin and clamp are this project's reading of the paper's pseudo-code "
               "(docs/variance_trading.md, 'The MSE rule as read here')"])


def draw(reproduction: Reproduction, path: Path) -> Path:
    return plot_panels(reproduction, [Panel("mse", "MSE at N samples"),
                                      Panel("variance", "variance (one sample)", log_y=False)],
                       path,
                       marked=at_target)


FIGURE = register(FigureSpec("vt", "fig5", "discrete test case of MSE minimization with "
                             "biased caches: MSE against sample count per target s, with the "
                             "exhaustive optimum", {"quick": QUICK, "full": FULL}, measure,
                             draw))
