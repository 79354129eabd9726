"""[VTT24] Fig. 9: MSE minimization at several sample targets s, as MSE against the
sample count N, one line per target (its marker at N = s), with the path tracer and
area-spread (c = 0.01) for reference.

Ours: `grid-cache` with `mse-min` on `cornell-box` and `white-room`, which stand in for
the paper's Bunny and Classroom (neither is a scene here), the paper's grid preset.
Each line is one render of K x F one-spp frames per target, its MSE at N samples
rBias² + rVar₁ / N (jobs/reproduce/measure.py: the cache's bias does not shrink with N,
one frame's variance does), relative as MRSE."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jobs.reproduce.measure import (
    MSE_NOTE,
    budget_settings,
    full_budget,
    grid_params,
    grid_presets,
    mse_at,
    quick_budget,
    sweep,
)
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Context, FigureSpec, register
from jobs.reproduce.results import Point, Reproduction, Verdict, apart

#: Our scenes for the paper's (Bunny, Classroom).
SCENES = {"cornell-box": "Bunny", "white-room": "Classroom"}
#: The sample counts N each line is evaluated at: 10^(k/2), 1 ... 10^4.
SAMPLE_COUNTS = tuple(float(round(10 ** (k / 2))) for k in range(9))
QUANTITIES = {"mse": "MSE at N samples (relative)"}
#: The claim's "sample counts below 100".
FAVOURABLE_BELOW = 100.0
PT = "PT (survival 90 %)"

QUICK = quick_budget((1.0, 10.0, 100.0, 1000.0))
FULL = full_budget((1.0, 10.0, 100.0, 1000.0, 10000.0))


def _line(scene: str, series: str, row: Any, run: Any) -> list[Point]:
    """One render's MSE at every sample count of :data:`SAMPLE_COUNTS`."""
    return [Point(scene=scene, series=series, x=n, run_id=row.id,
                  values={"mse": mse_at(row, run, n)}) for n in SAMPLE_COUNTS]


def measure(ctx: Context) -> Reproduction:
    points: list[Point] = []
    presets: set[str] = set()
    for scene in SCENES:
        for row, run in sweep(ctx, scene, "grid-cache", "termination_params.samples",
                              list(ctx.budget.values), grid_params(ctx, "mse-min", {})):
            presets |= grid_presets(run)
            points += _line(scene, f"mse-min s = {row.value:g}", row, run)
        [(row, run)] = sweep(ctx, scene, "grid-cache", "termination_params.c", [0.01],
                             grid_params(ctx, "area-spread", {}))
        points += _line(scene, "area-spread c = 0.01", row, run)
        [(row, run)] = sweep(ctx, scene, "pt", "rr_survival", [0.9], {})
        points += _line(scene, PT, row, run)
    return Reproduction(
        paper="vt", figure="fig9", title="[VTT24] Fig. 9: MSE minimization, MSE against "
                                         "sample count",
        mode="", settings=budget_settings(ctx, **{"runs' grid presets":
                                                  sorted(presets)}),
        x_label="sample count N", quantities=QUANTITIES, points=points,
        verdicts=verdicts(points),
        notes=[f"{ours} stands in for the paper's {theirs}" for ours, theirs in SCENES.items()]
        + ["each line's enlarged marker is its own sample target N = s; ideally each line "
           "is the lowest at its target", MSE_NOTE])


def at_target(point: Point) -> bool:
    """A point of an mse-min line at its own sample target."""
    return point.series.startswith("mse-min s = ") and point.x == float(
        point.series.removeprefix("mse-min s = "))


def _at(points: list[Point], scene: str, n: float) -> dict[str, Point]:
    return {p.series: p for p in points if p.scene == scene and p.x == n}


def lowest_at_target(points: list[Point]) -> Verdict:
    """Claim 1 ("partially observed"): holds when some mse-min line's interval at its
    target N = s lies below every other line's there; does not hold when at every target
    some other line's lies below it; not comparable otherwise."""
    lowest, beaten, parts = [], [], []
    for target in (p for p in points if at_target(p)):
        others = [o for name, o in _at(points, target.scene, target.x).items()
                  if name != target.series]
        order = [apart(target.values["mse"], o.values["mse"]) for o in others]
        lowest.append(all(o == -1 for o in order))
        beaten.append(any(o == 1 for o in order))
        best_other = min(others, key=lambda o: o.values["mse"].value or 0.0)
        parts.append(f"{target.scene} s = {target.x:g}: {target.values['mse'].text()}, "
                     + ("lowest" if lowest[-1] else "above another" if beaten[-1]
                        else "overlapping")
                     + f" (lowest other: {best_other.series} {best_other.values['mse'].text()})")
    kind = ("holds" if any(lowest) else "does not hold" if all(beaten)
            else "not comparable")
    return Verdict(claim="each mse-min line is lowest at its target, partially",
                   verdict=kind, reason=f"{sum(lowest)} of {len(lowest)} lowest: "
                   + "; ".join(parts))


def favourable_below_100(points: list[Point]) -> Verdict:
    """Claim 2 ("generally"): at every N below :data:`FAVOURABLE_BELOW` each mse-min
    line's interval against PT's; holds when more than half lie below and none above,
    does not hold when more lie above than below, not comparable otherwise."""
    counts = {-1: 0, 0: 0, 1: 0}
    for p in points:
        if p.series.startswith("mse-min") and p.x is not None and p.x < FAVOURABLE_BELOW:
            counts[apart(p.values["mse"], _at(points, p.scene, p.x)[PT].values["mse"])] += 1
    below, level, above = counts[-1], counts[0], counts[1]
    total = below + level + above
    kind = ("holds" if above == 0 and 2 * below > total else "does not hold"
            if above > below else "not comparable")
    return Verdict(claim="below N = 100 the mse-min lines lie below PT",
                   verdict=kind,
                   reason=f"of {total} mse-min points at N < {FAVOURABLE_BELOW:g}, {below} "
                          f"below PT's interval, {level} overlapping, {above} above")


def verdicts(points: list[Point]) -> list[Verdict]:
    return [lowest_at_target(points), favourable_below_100(points)]


def draw(reproduction: Reproduction, path: Path) -> Path:
    panels = [Panel("mse", f"{scene} (for {theirs})", scene=scene)
              for scene, theirs in SCENES.items()]
    return plot_panels(reproduction, panels, path, marked=at_target)


FIGURE = register(FigureSpec("vt", "fig9", "MSE minimization on cornell-box and white-room "
                             "(for Bunny, Classroom): MSE against sample count per target s, "
                             "PT and area-spread", {"quick": QUICK, "full": FULL}, measure,
                             draw))
