"""[VTT24] Fig. 11: variance bounding (t = 10) against area-spread (c = 0.01) on the
door after denoising: the denoised output, its FLIP and the path length per pixel.

Ours: the two policies' denoised `door` runs as in Fig. 10 (jobs/reproduce/vt_fig10.py:
`grid-cache`, t relative to the pixel's brightness, Intel Open Image Denoise standing in
for SVGF; area-spread's point is Fig. 10's own, read back from the store). The figure's
images are not drawn: their means are, per seed with intervals over the K seeds, and
where paths end (the share ending at the primary hit, as the path length maps show it)."""

from __future__ import annotations

from pathlib import Path

from jobs.reproduce.measure import budget_settings, grid_presets
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Context, FigureSpec, register
from jobs.reproduce.results import Estimate, Point, Reproduction, Verdict
from jobs.reproduce.vt_fig10 import (
    AREA_SPREAD,
    FULL,
    POLICIES,
    QUANTITIES,
    QUICK,
    SVGF_NOTE,
    policy_run,
    values_of,
)

SCENE = "door"
VAR_BOUND = "var-bound t = 10"
SERIES = ((VAR_BOUND, "grid-cache", "termination_params.threshold", 10.0,
           ("var-bound", {"relative": True})),
          next(p for p in POLICIES if p[0] == AREA_SPREAD))
X_LABEL = "policy, in the legend's order"
#: The denoised errors the first claim compares.
DENOISED = ("denoised_mrse_accum", "denoised_flip_accum")


def measure(ctx: Context) -> Reproduction:
    points: list[Point] = []
    presets: set[str] = set()
    for index, policy in enumerate(SERIES):
        row, run = policy_run(ctx, SCENE, policy)
        presets |= grid_presets(run)
        points.append(Point(scene=SCENE, series=policy[0], x=float(index), run_id=row.id,
                            values=values_of(run)))
    return Reproduction(
        paper="vt", figure="fig11", title="[VTT24] Fig. 11: var-bound t = 10 against "
                                          "area-spread on door, denoised",
        mode="", settings=budget_settings(ctx, **{"runs' grid presets": sorted(presets)}),
        x_label=X_LABEL, quantities=QUANTITIES, points=points, verdicts=verdicts(points),
        notes=[SVGF_NOTE, "var-bound's t is relative to the pixel's brightness",
               "not drawn: the figure's images (denoised output, FLIP and path length per "
               "pixel); the table holds their means over the pixels"])


def _order(a: Estimate, b: Estimate) -> int:
    """-1 when ``a``'s interval lies below ``b``'s, +1 above, 0 overlapping or missing."""
    if a.ci95 is None or b.ci95 is None:
        return 0
    return -1 if a.ci95[1] < b.ci95[0] else 1 if a.ci95[0] > b.ci95[1] else 0


def verdicts(points: list[Point]) -> list[Verdict]:
    """Claim 1: area-spread's denoised errors (4 frames, MRSE and FLIP) above var-bound's,
    intervals apart; claim 2: var-bound ends some paths at the primary hit."""
    by_series = {p.series: p.values for p in points}
    bound, spread = by_series.get(VAR_BOUND), by_series.get(AREA_SPREAD)
    if bound is None or spread is None:
        missing = Verdict(claim="", verdict="not comparable", reason="a policy's run is missing")
        return [missing.model_copy(update={"claim": c}) for c in (
            "area-spread's output worse for denoising", "var-bound ends paths at the primary "
                                                        "hit")]
    orders = [_order(spread[key], bound[key]) for key in DENOISED]
    detail = "; ".join(f"{QUANTITIES[key]}: area-spread {spread[key].text()}, var-bound "
                       f"{bound[key].text()}" for key in DENOISED)
    first = ("holds" if all(o > 0 for o in orders) else
             "does not hold" if all(o < 0 for o in orders) else "not comparable")
    reason = {"holds": "intervals apart, area-spread above", "does not hold":
              "intervals apart, area-spread below", "not comparable":
              "intervals overlap or the two errors disagree"}[first]
    primary = bound["primary_pct"].value
    second = ("not comparable" if primary is None else
              "holds" if primary > 0.0 else "does not hold")
    return [Verdict(claim="area-spread's output worse for denoising", verdict=first,
                    reason=f"{reason}: {detail}"),
            Verdict(claim="var-bound ends paths at the primary hit", verdict=second,
                    reason=f"var-bound: {bound['primary_pct'].text()} % of paths at the "
                           f"primary hit, area-spread {spread['primary_pct'].text()} %")]


def draw(reproduction: Reproduction, path: Path) -> Path:
    panels = [Panel(key, QUANTITIES[key], log_y=False) for key in
              ("mrse_frame", "denoised_mrse_accum", "denoised_flip_accum", "primary_pct")]
    return plot_panels(reproduction, panels, path, log_x=False)


FIGURE = register(FigureSpec("vt", "fig11", "var-bound t = 10 against area-spread on door "
                             "after OIDN (for SVGF): denoised MRSE and FLIP, path length and "
                             "paths ending at the primary hit (means, not the maps)",
                             {"quick": QUICK, "full": FULL}, measure, draw))
