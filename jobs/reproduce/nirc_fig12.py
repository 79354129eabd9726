"""[DKHD24] Fig. 12 (Sec. 6.3): termination heuristics for NIRC against NRC: the
spread-angle heuristic (SPH) for both, NIRC's balanced termination heuristic (BTH) and
the per-pixel adaptive termination: rBias², rVar, MRSE, FLIP and the bounces.

Ours: each heuristic is the methods' ``termination`` parameter (renderers/integrators/
termination: `nrc` serves ``sph`` and ``adaptive``; `nirc` also ``bth``, the paper's own
for incident radiance, so there is no NRC BTH series, nor one in the paper). SPH and BTH
are points of the generic parameter sweep (online training, pre-training
:data:`PRETRAIN_PER_FRAME` x F frames); the adaptive one is Fig. 13's equal-bias sweep
(jobs/reproduce/nirc_fig13.py) at the budget's one eps, without its equal-time series,
left out of ``--quick`` (:func:`with_adaptive`).
Bounces: the sweep's % indirect-radiance bounces (the invoking vertex's index less one,
averaged) and the average path vertices."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jobs.reproduce.measure import sweep
from jobs.reproduce.nirc_fig7 import flip, interval_order
from jobs.reproduce.nirc_fig13 import eps_sweep, sign_verdict
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Budget, Context, FigureSpec, register
from jobs.reproduce.results import Estimate, Point, Reproduction, Verdict

SCENES = ("white-room", "cornell-glossy", "door")
#: (series, method, termination, the method's parameters)
SERIES = (("NRC SPH", "nrc", "sph", {}),
          ("NIRC SPH", "nirc", "sph", {"estimator": "biased"}),
          ("NIRC BTH", "nirc", "bth", {"estimator": "biased"}))
ADAPTIVE = {"NIRC": "NIRC adaptive", "NRC": "NRC adaptive"}
ORDER = [s[0] for s in SERIES] + list(ADAPTIVE.values())


def x_label(adaptive: bool) -> str:
    """The x axis: each drawn series' position (the adaptive ones only where drawn)."""
    return "series: " + ", ".join(f"{i} {name}" for i, name in enumerate(ORDER)
                                  if adaptive or name not in ADAPTIVE.values())


QUANTITIES = {"rbias2": "rBias²", "rvar": "rVar", "mrse": "MRSE", "flip": "FLIP",
              "ir_bounces_pct": "% IR bounces", "path_vertices": "path vertices"}
PRETRAIN_PER_FRAME = 2

QUICK_WHY = ("--quick: 16x16, K = 3 seeds of F = 4 frames after 8 pre-training frames; no "
             "adaptive series (the claims do not compare it; its eps 0.2 points are Fig. "
             "13's --quick points at that eps); the paper trains its caches for thousands "
             "of frames at 1080p")
FULL_WHY = "--full: 64x64, K = 4, F = 64 after 128 pre-training frames, adaptive at eps 0.2"
QUICK = Budget(resolution=16, seeds=3, frames=4, ref_spp=256, grid_preset="—", why=QUICK_WHY,
               values=(0.2,))
FULL = Budget(resolution=64, seeds=4, frames=64, ref_spp=1024, grid_preset="—",
              why=FULL_WHY, values=(0.2,))


def with_adaptive(budget: Budget) -> bool:
    """Whether the adaptive series is drawn: not at --quick, where its caches would be
    most of the figure's cost (three scenes' snapshots) and no claim compares it; Fig.
    13's --quick run holds the same points (its eps 0.2) on white-room and cornell-glossy."""
    return budget != QUICK


def values_of(row: Any, run: Any) -> dict[str, Estimate]:
    """A sweep row's errors with their intervals, FLIP's over the seeds, and bounces."""
    values = {key: Estimate(value=getattr(row, key), ci95=getattr(row, f"{key}_ci95"),
                            note=f"{key}: {getattr(row, f'{key}_ci_note')}")
              for key in ("rbias2", "rvar", "mrse")}
    values["flip"] = flip(run, row.flip)
    values["ir_bounces_pct"] = Estimate(value=row.ir_bounces_pct)
    values["path_vertices"] = Estimate(value=row.avg_path_length)
    return values


def measure(ctx: Context) -> Reproduction:
    b = ctx.budget
    points: list[Point] = []
    for scene in SCENES:
        for series, method, policy, params in SERIES:
            [(row, run)] = sweep(ctx, scene, method, "termination", [policy],
                                 {**params, "pretrain_frames": PRETRAIN_PER_FRAME * b.frames})
            points.append(Point(scene=scene, series=series, x=float(ORDER.index(series)),
                                run_id=row.id, values=values_of(row, run)))
        if not with_adaptive(b):
            continue
        for row, run in eps_sweep(ctx, scene, equal_time=False):
            series = ADAPTIVE[row.series]
            points.append(Point(scene=scene, series=series, x=float(ORDER.index(series)),
                                run_id=row.id, values=values_of(row, run)))
    return Reproduction(
        paper="nirc", figure="fig12", title="[DKHD24] Fig. 12: termination heuristics, NIRC "
                                            "against NRC",
        mode="", settings={"resolution": f"{b.resolution}x{b.resolution}", "seeds K": b.seeds,
                           "frames F": b.frames,
                           "pre-training frames": PRETRAIN_PER_FRAME * b.frames,
                           "adaptive eps": list(b.values) if with_adaptive(b) else "—", "reference spp": b.ref_spp,
                           "why": b.why},
        x_label=x_label(with_adaptive(b)), quantities=QUANTITIES, points=points, verdicts=verdicts(points),
        notes=["our scenes are the project's built-ins: white-room is the paper's White "
               "Room, cornell-glossy stands for Glossy Sponza, door for the indirectly lit "
               "Bistro Exterior",
               "no NRC BTH series: BTH is NIRC's heuristic for incident radiance (nrc "
               "serves sph and adaptive), as in the paper",
               "the adaptive series' caches are frozen after training (the equal-bias "
               "protocol), the SPH and BTH series train online"])


def _get(points: list[Point], scene: str, series: str) -> Point | None:
    return next((p for p in points if (p.scene, p.series) == (scene, series)), None)


def _ratio(a: Estimate, b: Estimate) -> str:
    return f"{a.value / b.value:.2f}x" if a.value and b.value else "—"


def verdicts(points: list[Point]) -> list[Verdict]:
    sph_signs, sph_detail = [], []
    bth_signs, bth_detail = [], []
    for scene in SCENES:
        nrc, sph, bth = (_get(points, scene, s) for s in ("NRC SPH", "NIRC SPH", "NIRC BTH"))
        if nrc is not None and sph is not None:
            sph_signs.append(interval_order(sph.values["rbias2"], nrc.values["rbias2"]))
            sph_detail.append(f"{scene}: {sph.values['rbias2'].text()} vs "
                              f"{nrc.values['rbias2'].text()} (NRC / NIRC "
                              f"{_ratio(nrc.values['rbias2'], sph.values['rbias2'])})")
        if sph is not None and bth is not None:
            bth_signs.append(bth_against_sph(bth, sph))
            bth_detail.append(
                f"{scene}: rVar {bth.values['rvar'].text()} vs {sph.values['rvar'].text()}, "
                f"rBias² {bth.values['rbias2'].text()} vs {sph.values['rbias2'].text()}, "
                f"% IR bounces SPH / BTH "
                f"{_ratio(sph.values['ir_bounces_pct'], bth.values['ir_bounces_pct'])}")
    return [
        sign_verdict("NIRC with SPH has lower rBias² than NRC with SPH", sph_signs,
                     "; ".join(sph_detail), "up to 4.12x lower rBias²"),
        sign_verdict("NIRC's BTH: lower rVar and fewer bounces than its SPH, at a higher "
                     "rBias²", bth_signs, "; ".join(bth_detail),
                     "less noise, up to 3.54x fewer bounces, more bias"),
    ]


def bth_against_sph(bth: Point, sph: Point) -> int:
    """+1 when BTH has the lower rVar and the higher rBias² (intervals apart) and fewer
    % IR bounces than SPH; -1 when its rVar is higher (apart) or its bounces more; else 0."""
    var = interval_order(bth.values["rvar"], sph.values["rvar"])
    bias = interval_order(sph.values["rbias2"], bth.values["rbias2"])
    bounces_bth = bth.values["ir_bounces_pct"].value
    bounces_sph = sph.values["ir_bounces_pct"].value
    fewer = None if bounces_bth is None or bounces_sph is None else bounces_bth < bounces_sph
    if var == -1 or fewer is False:
        return -1
    return 1 if var == 1 and bias == 1 and fewer else 0


def draw(reproduction: Reproduction, path: Path) -> Path:
    return plot_panels(reproduction, [Panel(key, f"{scene}: {QUANTITIES[key]}", scene=scene)
                                      for scene in SCENES for key in ("rbias2", "rvar")],
                       path, log_x=False)


FIGURE = register(FigureSpec("nirc", "fig12", "Termination heuristics: SPH for NIRC and NRC, "
                             "NIRC's BTH and the per-pixel adaptive termination (rBias², "
                             "rVar, MRSE, FLIP, bounces)", {"quick": QUICK, "full": FULL},
                             measure, draw))
