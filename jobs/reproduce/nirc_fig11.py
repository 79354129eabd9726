"""[DKHD24] Fig. 11: NIRC against the neural visibility cache (NVC) for direct
illumination with MLMC, N_c = 7, over training.

Ours: unbiased `nirc` (``nc = [7]``: the cache serves the direct and indirect light)
against unbiased `nirc-nvc-env` (NIRC with N_c 7 for indirect light, the environment's
visibility cache with N_c 7 for its direct light, both levels' residuals traced) on sky,
the scene lit by the environment map the visibility cache samples. Each point trains
from scratch for its pre-training frames and renders F frames (the generic parameter
sweep over ``pretrain_frames``); MRSE and FLIP with their intervals, rVar (the seeds'
spread of the render: the variance left by the two-level estimator and the caches'
differences) and, for NIRC, V_rel of its residual estimator. `nirc-nvc-env` has no
residual probe: its V_rel is not measured."""

from __future__ import annotations

from pathlib import Path

from jobs.reproduce.measure import metric, sweep
from jobs.reproduce.nirc_fig6 import v_rel
from jobs.reproduce.nirc_fig7 import flip, interval_order
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Budget, Context, FigureSpec, register
from jobs.reproduce.results import Point, Reproduction, Verdict

SCENE = "sky"
NC = 7
#: (series, method, its parameters)
SERIES = (
    ("NIRC", "nirc", {"estimator": "unbiased", "nc": [NC]}),
    ("NVC", "nirc-nvc-env", {"estimator": "unbiased", "nc": [NC],
                             "env_estimator": "unbiased", "env_nc": NC}),
)
QUANTITIES = {"mrse": "MRSE", "flip": "FLIP", "rvar": "rVar", "v_rel": "V_rel(<F_r>)"}

QUICK_WHY = ("--quick: 16x16, K = 4 seeds of F = 4 frames after 0 and 48 pre-training "
             "frames (the paper trains over thousands of frames at 1080p; the verdict reads "
             "the last point, the first shows the start of training; a point at 16 was a "
             "third of the figure's time)")
FULL_WHY = "--full: 64x64, K = 8, F = 16 after 0-1024 pre-training frames"
QUICK = Budget(resolution=16, seeds=4, frames=4, ref_spp=1024, grid_preset="—", why=QUICK_WHY,
               values=(0.0, 48.0))
FULL = Budget(resolution=64, seeds=8, frames=16, ref_spp=4096, grid_preset="—",
              why=FULL_WHY, values=(0.0, 64.0, 256.0, 1024.0))


def measure(ctx: Context) -> Reproduction:
    b = ctx.budget
    points: list[Point] = []
    for series, method, params in SERIES:
        for row, run in sweep(ctx, SCENE, method, "pretrain_frames",
                              [int(v) for v in b.values], dict(params)):
            points.append(Point(scene=SCENE, series=series, x=float(row.value) + b.frames,
                                run_id=row.id,
                                values={"mrse": metric(row, "mrse"), "flip": flip(run, row.flip),
                                        "rvar": metric(row, "rvar"), "v_rel": v_rel(run)}))
    return Reproduction(
        paper="nirc", figure="fig11", title="[DKHD24] Fig. 11: NIRC against NVC for direct "
                                            "illumination, N_c = 7",
        mode="", settings={"resolution": f"{b.resolution}x{b.resolution}", "seeds K": b.seeds,
                           "frames F": b.frames, "N_c": NC, "why": b.why},
        x_label="training frames (pre-training + F)", quantities=QUANTITIES, points=points,
        verdicts=[verdict(points)],
        notes=["NVC: `nirc-nvc-env`, NIRC for indirect light and the environment's "
               "visibility cache for its direct light, both unbiased (module doc)",
               "V_rel: NIRC's only; `nirc-nvc-env` has no residual probe",
               "San Miguel is not built in; sky is lit by the environment map the "
               "visibility cache samples"])


def verdict(points: list[Point]) -> Verdict:
    """At the most training frames: holds when NVC's MRSE and rVar both lie below NIRC's
    (intervals apart); does not hold when either lies above; not comparable otherwise."""
    claim = "NVC reconstructs better and trains more stably than NIRC"
    last = max((p.x for p in points if p.x is not None), default=None)
    found = {p.series: p for p in points if p.x == last}
    if last is None or set(found) != {"NIRC", "NVC"}:
        return Verdict(claim=claim, verdict="not comparable", reason="a series lacks points")
    nvc, nirc = found["NVC"], found["NIRC"]
    signs = [interval_order(nvc.values[k], nirc.values[k]) for k in ("mrse", "rvar")]
    text = (f"after {last:g} frames NVC / NIRC MRSE {nvc.values['mrse'].text()} / "
            f"{nirc.values['mrse'].text()}, FLIP {nvc.values['flip'].text()} / "
            f"{nirc.values['flip'].text()}, rVar {nvc.values['rvar'].text()} / "
            f"{nirc.values['rvar'].text()}")
    if signs == [1, 1]:
        return Verdict(claim=claim, verdict="holds",
                       reason=f"lower MRSE and rVar, intervals apart; {text}")
    if -1 in signs:
        return Verdict(claim=claim, verdict="does not hold",
                       reason=f"higher MRSE or rVar, intervals apart; {text}")
    return Verdict(claim=claim, verdict="not comparable", reason=f"intervals overlap; {text}")


def draw(reproduction: Reproduction, path: Path) -> Path:
    return plot_panels(reproduction, [Panel(key, label) for key, label in QUANTITIES.items()],
                       path, log_x=False)


FIGURE = register(FigureSpec("nirc", "fig11", "NIRC against NIRC with the environment's "
                             "visibility cache for direct light, N_c = 7, on sky: MRSE, FLIP, "
                             "rVar and V_rel over training frames",
                             {"quick": QUICK, "full": FULL}, measure, draw))
