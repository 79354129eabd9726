"""[DKHD24] Fig. 13 (Sec. 6.3): per-pixel adaptive termination swept over eps, NIRC
against NRC: MRSE, FLIP, rBias² and rVar against the % indirect-radiance (IR) bounces.

Ours: the adaptive equal-bias sweep (`nirc-bench sweep --eps`, jobs/sweeps/sweep.py):
per method and seed a trained cache's converged cache-at-v1 image gives each pixel's
relative bias, and at each eps the cache is used at v1 where it is below eps (the
spread heuristic elsewhere); series NIRC (N_c 1), NRC and "NIRC equal time" (N_c at v1
calibrated to the NRC point of the closest rBias²). The x axis is the sweep's
``ir_bounces_pct`` (the invoking vertex's index less one, averaged, in %)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from jobs.reproduce.nirc_fig7 import flip, interval_order
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Budget, Context, FigureSpec, register
from jobs.reproduce.results import Estimate, Point, Reproduction, Verdict

SCENES = ("white-room", "cornell-glossy")
QUANTITIES = {"mrse": "MRSE", "flip": "FLIP", "rbias2": "rBias²", "rvar": "rVar"}
#: N_c candidates of the equal-time series (the sweep's default goes to 32).
NC_CANDIDATES = [1, 2, 4, 8]
#: Two points are at "the same % IR bounces" when they differ by at most this (points).
SAME_BOUNCES = 5.0
#: Each cache trains this many frames per rendered frame before its snapshot: fewer at
#: the --quick size (:func:`train_frames`).
TRAIN_PER_FRAME = 8
QUICK_TRAIN_PER_FRAME = 4

QUICK_WHY = ("--quick: 16x16, K = 3 seeds of F = 4 frames, caches trained 16 frames, "
             "cache-at-v1 images of 64 spp, eps 0.05, 0.2, 1; equal-time probes timed on a "
             "loaded machine are used (noted); the paper trains 2000 frames at 1080p")
FULL_WHY = ("--full: 64x64, K = 4, F = 16, 128 training frames, 256-spp cache-at-v1 "
            "images, eps 0.02-1, loaded probes taken again")
QUICK = Budget(resolution=16, seeds=3, frames=4, ref_spp=256, grid_preset="—", why=QUICK_WHY,
               values=(0.05, 0.2, 1.0))
FULL = Budget(resolution=64, seeds=4, frames=16, ref_spp=1024, grid_preset="—",
              why=FULL_WHY, values=(0.02, 0.05, 0.1, 0.2, 0.5, 1.0))


def train_frames(budget: Budget) -> int:
    """Frames each cache trains before its snapshot: :data:`QUICK_TRAIN_PER_FRAME` per
    rendered frame at the --quick size or below (Fig. 12's adaptive series shares
    these caches), :data:`TRAIN_PER_FRAME` above."""
    per_frame = QUICK_TRAIN_PER_FRAME if budget.resolution <= QUICK.resolution else TRAIN_PER_FRAME
    return per_frame * budget.frames


def eps_sweep(ctx: Context, scene: str, equal_time: bool = True,
              allow_loaded: bool = False) -> list[tuple[Any, Any]]:
    """(sweep row, stored run) of the adaptive sweep of ``scene`` at the budget's eps
    values (stored points are read back, not rendered); ``equal_time``: with the "NIRC
    equal time" series, ``allow_loaded`` its calibration's timings on a loaded machine."""
    from jobs.protocol.spec import ReferenceSpec, SweepSpec
    from jobs.sweeps.sweep import run_sweep

    b = ctx.budget
    spec = SweepSpec(scene=scene, eps=list(b.values), nc=NC_CANDIDATES, methods=["nirc", "nrc"],
                     resolution=b.resolution, seeds=b.seeds, frames=b.frames,
                     train_frames=train_frames(b), v1_spp=b.ref_spp // 4,
                     equal_time=equal_time, allow_loaded=allow_loaded,
                     reference=ReferenceSpec(spp=b.ref_spp))
    result = run_sweep(spec, ctx.store, ctx.settings, progress=ctx.progress, plots=False)
    for name in ("points_rendered", "points_reused"):
        ctx.work[name] = ctx.work.get(name, 0) + result.work.get(name, 0)
    return [(row, ctx.store.get_run(row.id)) for row in result.rows]


def point(scene: str, row: Any, run: Any) -> Point:
    values = {key: Estimate(value=getattr(row, key), ci95=getattr(row, f"{key}_ci95"),
                            note=f"{key}: {getattr(row, f'{key}_ci_note')}")
              for key in ("mrse", "rbias2", "rvar")}
    values["flip"] = flip(run, row.flip)
    return Point(scene=scene, series=row.series, x=row.ir_bounces_pct, run_id=row.id,
                 values=values)


def measure(ctx: Context) -> Reproduction:
    b = ctx.budget
    points, chosen, same_as_nirc = [], [], set()
    for scene in SCENES:
        rows = eps_sweep(ctx, scene, allow_loaded=b == QUICK)
        nirc_renders = {row.render_key for row, _run in rows if row.series == "NIRC"}
        for row, run in rows:
            points.append(point(scene, row, run))
            if row.series.endswith("equal time"):
                chosen.append(f"{scene} eps {row.eps:g}: N_c {row.nc}")
                if row.render_key is not None and row.render_key in nirc_renders:
                    same_as_nirc.add(row.id)
    return Reproduction(
        paper="nirc", figure="fig13", title="[DKHD24] Fig. 13: adaptive termination over eps, "
                                            "NIRC against NRC",
        mode="", settings={"resolution": f"{b.resolution}x{b.resolution}", "seeds K": b.seeds,
                           "frames F": b.frames, "eps": list(b.values),
                           "training frames": train_frames(b),
                           "reference spp": b.ref_spp, "why": b.why},
        x_label="% IR bounces", quantities=QUANTITIES, points=points,
        verdicts=verdicts(points, same_as_nirc),
        notes=["our scenes are the project's built-ins: white-room is the paper's White Room, "
               "cornell-glossy stands for Glossy Sponza",
               "each row is one eps; the equal-time series' calibrated N_c at v1: "
               + (", ".join(chosen) or "none")])


# ---- Verdicts ----

def sign_verdict(claim: str, signs: list[int], detail: str, paper: str) -> Verdict:
    """Holds when every comparison is +1 (ours lower, intervals apart), does not hold
    when one is -1, not comparable otherwise or with none."""
    if not signs:
        return Verdict(claim=claim, verdict="not comparable",
                       reason=f"no pair of points to compare; the paper: {paper}")
    verdict = ("does not hold" if -1 in signs else "holds" if all(s == 1 for s in signs)
               else "not comparable")
    why = {"holds": "lower with intervals apart in every pair",
           "does not hold": "higher with intervals apart in a pair",
           "not comparable": "intervals overlap in a pair"}[verdict]
    return Verdict(claim=claim, verdict=verdict, reason=f"{why}; {detail}; the paper: {paper}")


def pairs(points: list[Point], ours: str, theirs: str,
          together: Callable[[Point, Point], bool]) -> list[tuple[Point, Point]]:
    """(ours, theirs) points of the two series, same scene, for which ``together`` holds."""
    return [(a, b) for a in points if a.series == ours for b in points
            if b.series == theirs and a.scene == b.scene and together(a, b)]


def _same_bounces(a: Point, b: Point) -> bool:
    return a.x is not None and b.x is not None and abs(a.x - b.x) <= SAME_BOUNCES


def closest_bias(points: list[Point], a: Point, b: Point) -> bool:
    """``b`` is the NRC point of ``a``'s scene whose rBias² is closest to ``a``'s (the
    sweep's equal-time match), their intervals overlapping: the same bias."""
    def distance(p: Point) -> float:
        ours, theirs = a.values["rbias2"].value, p.values["rbias2"].value
        return abs(ours - theirs) if ours is not None and theirs is not None else float("inf")

    nrc = [p for p in points if p.series == b.series and p.scene == a.scene]
    return (min(nrc, key=distance) is b
            and interval_order(a.values["rbias2"], b.values["rbias2"]) == 0)


def _compare(found: list[tuple[Point, Point]], key: str) -> tuple[list[int], str]:
    signs = [interval_order(a.values[key], b.values[key]) for a, b in found]
    detail = ", ".join(f"{a.scene} {a.x:.0f} % against {b.x:.0f} %: {a.values[key].text()} "
                       f"vs {b.values[key].text()}" for a, b in found
                       if a.x is not None and b.x is not None)
    return signs, detail


def verdicts(points: list[Point], same_as_nirc: set[int | None]) -> list[Verdict]:
    """The claims of Fig. 13; ``same_as_nirc``: the equal-time points that render what a
    NIRC point does (N_c 1 chosen), left out of the comparison with N_c 1."""
    bias, bias_detail = _compare(pairs(points, "NIRC", "NRC", _same_bounces), "rbias2")
    var, var_detail = _compare(
        pairs(points, "NIRC", "NRC", lambda a, b: closest_bias(points, a, b)), "rvar")
    nc, nc_detail = _compare(
        pairs(points, "NIRC equal time", "NIRC",
              lambda a, b: a.run_id not in same_as_nirc and _same_bounces(a, b)), "rvar")
    return [
        sign_verdict(f"NIRC's rBias² below NRC's at the same % IR bounces (within "
                     f"{SAME_BOUNCES:g} points)", bias, f"rBias² NIRC vs NRC: {bias_detail}",
                     "lower bias for any % IR bounces"),
        sign_verdict("NIRC's rVar below NRC's at the same bias (the NRC point of closest "
                     "rBias², intervals overlapping)", var, f"rVar NIRC vs NRC: {var_detail}",
                     "lower variance wherever NRC reaches the same bias"),
        sign_verdict("more neural samples (NIRC equal time, N_c above 1) lower the variance "
                     "against N_c 1", nc, f"rVar: {nc_detail}",
                     "variance 1.11-1.82x, MRSE 0.93-6.67x, FLIP 1.05-1.14x better"),
    ]


def draw(reproduction: Reproduction, path: Path) -> Path:
    return plot_panels(reproduction, [Panel(key, f"{scene}: {label}", scene=scene)
                                      for scene in SCENES
                                      for key, label in QUANTITIES.items()
                                      if key in ("mrse", "rbias2")], path, log_x=False)


FIGURE = register(FigureSpec("nirc", "fig13", "Per-pixel adaptive termination swept over "
                             "eps: MRSE, FLIP, rBias² and rVar against % IR bounces, NIRC, "
                             "NRC and NIRC at equal time", {"quick": QUICK, "full": FULL},
                             measure, draw))
