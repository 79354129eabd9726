"""[VTT24] Table 1: variance bounding (absolute t), MSE minimization and area-spread on
Door and Corridor: the tracer's and the propagation's time and the path length, here
beside the paper's numbers (papers/variance_trading.toml) and the order of the policies
by path length.

Ours: `grid-cache` with each policy at the paper's settings and plain `pt`, every row a
point of the generic parameter sweep (the policy's parameter swept by its dotted name),
on the project's `door` and `corridor`; every row with Fig. 7's 60 % series' path
settings (jobs/reproduce/vt_fig7.py: the roulette survives 60 % from the fifth vertex,
paths of at most 16 segments; the paper does not state its own for Table 1), so that
the var-bound rows on door are Fig. 7's stored points, rendered once. ``--full`` adds relative
variance bounding (Sec. 5) at the budget's thresholds. Times are kernel milliseconds of
the median frame, on this machine's CPU: only their order is comparable with the
paper's GPU at 1080p."""

from __future__ import annotations

import math
from itertools import combinations, pairwise
from pathlib import Path
from typing import Any

from jobs.reproduce.measure import (
    budget_settings,
    full_budget,
    grid_params,
    grid_presets,
    kernel_ms,
    metric,
    path_length,
    quick_budget,
    sweep,
)
from jobs.reproduce.papers import paper_data
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Context, FigureSpec, register
from jobs.reproduce.results import Point, Reproduction, Verdict, apart, kind_of
from jobs.reproduce.vt_fig7 import MAX_DEPTH, SURVIVALS

#: Our scenes, by the paper's names.
SCENES = {"door": "Door", "corridor": "Corridor"}
#: (policy, parameter, values, fixed policy parameters, label of the parameter): the
#: paper's rows.
POLICIES: tuple[tuple[str, str, list[float], dict[str, Any], str], ...] = (
    ("var-bound", "threshold", [0.01, 0.1, 1.0], {"relative": False}, "t"),
    ("mse-min", "samples", [100.0], {}, "s"),
    ("area-spread", "c", [0.01, 100.0], {}, "c"),
)
#: Fig. 7's 60 % survival (module doc).
RR_SURVIVAL = SURVIVALS[1]
QUANTITIES = {"mrse": "MRSE", "rvar": "rVar", "rbias2": "rBias²",
              "path_length": "path length (paper's)", "tracer_ms": "tracer ms (kernels)",
              "propagation_ms": "propagation ms (kernels)"}

#: "an average path length of almost 2": our reading, within 10 % of 2 vertices.
ALMOST_TWO = (1.8, 2.2)

QUICK = quick_budget()
FULL = full_budget((0.01, 0.1, 1.0, 10.0))


def _point(scene: str, series: str, x: float | None, row: Any, run: Any,
           paper: dict[str, float]) -> Point:
    return Point(scene=scene, series=series, x=x, run_id=row.id, paper=paper, values={
        "mrse": metric(row, "mrse"), "rvar": metric(row, "rvar"),
        "rbias2": metric(row, "rbias2"), "path_length": path_length(run),
        "tracer_ms": kernel_ms(row, "render"), "propagation_ms": kernel_ms(row, "propagation")})


def _paper_values(scene: str, policy: str, setting: float) -> dict[str, float]:
    values, _claims = paper_data("vt").of("table1")
    return {v.quantity: v.value for v in values
            if (v.scene, v.series, v.setting) == (SCENES[scene], policy, setting)}


def policy_order(points: list[Point], scene: str, key: str) -> tuple[list[str], int, int]:
    """The paper's rows of ``scene`` ordered by the paper's path length, and how many of
    their pairs our path lengths order alike, of how many (ties in either count apart)."""
    rows = [p for p in points if p.scene == scene and "path_length" in p.paper
            and p.values["path_length"].value is not None]
    rows.sort(key=lambda p: p.paper["path_length"])
    agree = total = 0
    for a, b in combinations(rows, 2):
        theirs = b.paper["path_length"] - a.paper["path_length"]
        ours = b.values[key].value - a.values[key].value   # type: ignore[operator]
        if theirs != 0 and ours != 0:
            total += 1
            agree += (theirs > 0) == (ours > 0)
    return [p.series if p.x is None else f"{p.series} {p.x:g}" for p in rows], agree, total


def area_spread_near_two(points: list[Point]) -> Verdict:
    """Claim 1: area-spread (c = 0.01)'s path length in every scene, its interval inside
    :data:`ALMOST_TWO` (holds), outside it (does not hold) or across an end."""
    rows = [p for p in points if p.series == "area-spread (c)" and p.x == 0.01]
    inside, outside = [], []
    for p in rows:
        low, high = p.values["path_length"].ci95 or (-math.inf, math.inf)
        inside.append(ALMOST_TWO[0] <= low and high <= ALMOST_TWO[1])
        outside.append(high < ALMOST_TWO[0] or low > ALMOST_TWO[1])
    lengths = ", ".join(f"{p.scene} {p.values['path_length'].text()} (the paper's "
                        f"{p.paper.get('path_length', math.nan):g})" for p in rows)
    return Verdict(claim="area-spread c = 0.01 paths average almost 2 vertices",
                   verdict=kind_of(inside, outside) if rows else "not comparable",
                   reason=f"path length {lengths}; 'almost 2' read as {ALMOST_TWO[0]:g}"
                          f"-{ALMOST_TWO[1]:g}")


def longer_with_threshold(points: list[Point]) -> Verdict:
    """Claim 2, per scene: each larger var-bound t gives longer paths and a longer tracer
    time (intervals apart; a time is one median frame without an interval, so it settles
    nothing)."""
    resolved, contrary, parts = [], [], []
    for scene in SCENES:
        rows = sorted((p for p in points if p.scene == scene and p.series == "var-bound (t)"),
                      key=lambda p: p.x or 0.0)
        for key in ("path_length", "tracer_ms"):
            steps = [apart(b.values[key], a.values[key]) for a, b in pairwise(rows)]
            resolved.append(all(step == 1 for step in steps))
            contrary.append(any(step == -1 for step in steps))
            parts.append(f"{scene} {QUANTITIES[key]} " + " -> ".join(
                p.values[key].text() for p in rows) + f" ({steps.count(1)} of {len(steps)} "
                "steps apart" + ("; medians without intervals" if any(
                    p.values[key].ci95 is None for p in rows) else "") + ")")
    ts = ", ".join(f"{p.x:g}" for p in points if p.scene == "door"
                   and p.series == "var-bound (t)")
    return Verdict(claim="larger thresholds give longer paths and longer times",
                   verdict=kind_of(resolved, contrary),
                   reason=f"at t = {ts}: " + "; ".join(parts))


def verdicts(points: list[Point]) -> list[Verdict]:
    return [area_spread_near_two(points), longer_with_threshold(points)]


def measure(ctx: Context) -> Reproduction:
    points: list[Point] = []
    presets: set[str] = set()
    for scene in SCENES:
        [(row, run)] = sweep(ctx, scene, "pt", "rr_survival", [RR_SURVIVAL], {},
                             max_depth=MAX_DEPTH)
        points.append(_point(scene, f"PT (survival {RR_SURVIVAL:.0%})", None, row, run, {}))
        series = [(*policy, "") for policy in POLICIES]
        if ctx.budget.values:
            series.append(("var-bound", "threshold", list(ctx.budget.values),
                           {"relative": True}, "t", " (relative)"))
        for policy, name, values, fixed, symbol, suffix in series:
            for row, run in sweep(ctx, scene, "grid-cache", f"termination_params.{name}",
                                  values, grid_params(ctx, policy, fixed,
                                                      rr_survival=RR_SURVIVAL),
                                  max_depth=MAX_DEPTH):
                presets |= grid_presets(run)
                paper = {} if suffix else _paper_values(scene, policy, float(row.value))
                points.append(_point(scene, f"{policy}{suffix} ({symbol})", float(row.value),
                                     row, run, paper))
    notes = [f"roulette survival {RR_SURVIVAL:.0%} from the fifth vertex and paths of at "
             f"most {MAX_DEPTH} segments in every row (Fig. 7's {RR_SURVIVAL:.0%} series: its "
             "var-bound points on door are these rows)",
             "times: kernel ms of the median frame on this machine's CPU; the paper's are "
             "an RTX 3070 Ti's at 1920x1080: compare their order, not their values"]
    for scene, theirs in SCENES.items():
        order, agree, total = policy_order(points, scene, "path_length")
        notes.append(f"{scene} (the paper's {theirs}): of the {total} pairs of the paper's "
                     f"rows whose path lengths differ in both, {agree} are ordered alike "
                     f"(the paper's order, shortest first: {', '.join(order)})")
    return Reproduction(
        paper="vt", figure="table1", title="[VTT24] Table 1: path length and time per policy",
        mode="", settings=budget_settings(ctx, **{"runs' grid presets": sorted(presets)}),
        x_label="parameter", quantities=QUANTITIES, points=points, notes=notes,
        verdicts=verdicts(points))


def draw(reproduction: Reproduction, path: Path) -> Path:
    """Our path length against each policy's parameter, one panel per scene (the paper's
    values are in the table beside ours)."""
    return plot_panels(reproduction, [Panel("path_length", f"{scene}: path length",
                                            log_y=False, scene=scene) for scene in SCENES],
                       path)


FIGURE = register(FigureSpec("vt", "table1", "path length and tracer/propagation time of "
                             "each policy on door and corridor, beside the paper's Table 1",
                             {"quick": QUICK, "full": FULL}, measure, draw))
