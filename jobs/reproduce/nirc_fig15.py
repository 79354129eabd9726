"""[DKHD24] Fig. 15: the cache's hidden layers D against the error of its incident
radiance, and the time per frame.

Ours: biased `nirc` swept over ``cache.mlp.hidden_layers`` (the generic parameter
sweep), every path terminated into the cache at its first vertex (``adaptive``
termination without a v1 mask: every pixel may), so that the image's squared bias
(rBias², per cache) is the error of the cache's incident radiance integrated there with
N_c samples: a stand-in for the paper's MSE of the cache against reference incident
radiance at chosen points, which the project does not compute."""

from __future__ import annotations

from pathlib import Path

from jobs.reproduce.measure import frame_ms, metric, sweep
from jobs.reproduce.nirc_fig7 import interval_order
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Budget, Context, FigureSpec, register
from jobs.reproduce.results import Point, Reproduction, Verdict

SCENES = ("cornell-box", "white-room")
PARAMS = {"estimator": "biased", "termination": "adaptive"}
PRETRAIN_PER_FRAME = 8
QUANTITIES = {"rbias2": "rBias² (cache at v1)", "mrse": "MRSE", "ms_per_frame": "ms per frame"}

QUICK_WHY = ("--quick: 16x16, K = 3 seeds of F = 4 frames after 32 pre-training frames, "
             "D 1, 3, 6: the shallowest and deepest the verdict compares and one between "
             "(the paper trains thousands of frames at 1080p)")
FULL_WHY = "--full: 64x64, K = 4, F = 16 after 512 pre-training frames, D 1-8"
QUICK = Budget(resolution=16, seeds=3, frames=4, ref_spp=256, grid_preset="—", why=QUICK_WHY,
               values=(1.0, 3.0, 6.0))
FULL = Budget(resolution=64, seeds=4, frames=16, ref_spp=1024, grid_preset="—",
              why=FULL_WHY, values=(1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0))


def measure(ctx: Context) -> Reproduction:
    b = ctx.budget
    points: list[Point] = []
    for scene in SCENES:
        for row, _run in sweep(ctx, scene, "nirc", "cache.mlp.hidden_layers",
                               [int(d) for d in b.values],
                               {**PARAMS, "pretrain_frames": PRETRAIN_PER_FRAME * b.frames}):
            points.append(Point(scene=scene, series=scene, x=float(row.value), run_id=row.id,
                                values={"rbias2": metric(row, "rbias2"),
                                        "mrse": metric(row, "mrse"),
                                        "ms_per_frame": frame_ms(row)}))
    return Reproduction(
        paper="nirc", figure="fig15", title="[DKHD24] Fig. 15: hidden layers D against the "
                                            "cache's error",
        mode="", settings={"resolution": f"{b.resolution}x{b.resolution}", "seeds K": b.seeds,
                           "frames F": b.frames,
                           "pre-training frames": PRETRAIN_PER_FRAME * b.frames,
                           "why": b.why},
        x_label="hidden layers D", quantities=QUANTITIES, points=points,
        verdicts=[verdict(points)],
        notes=["the cache's error: rBias² of the image with every path ended into the cache "
               "at v1 (module doc), not the paper's MSE of incident radiance at chosen points",
               "Cornell Box and White Room are built in; New Sponza is not"])


def verdict(points: list[Point]) -> Verdict:
    """Holds when the deepest D's rBias² lies below the shallowest's (intervals apart) on
    most scenes (the paper: 'typically', not on every one); does not hold when it is
    above on some scene and below on none; not comparable otherwise."""
    claim = "more hidden layers lower the cache's error on most scenes"
    signs, detail = [], []
    for scene in SCENES:
        found = sorted((p for p in points if p.scene == scene and p.x is not None),
                       key=lambda p: p.x or 0.0)
        if len(found) < 2:
            continue
        shallow, deep = found[0], found[-1]
        signs.append(interval_order(deep.values["rbias2"], shallow.values["rbias2"]))
        detail.append(f"{scene}: D {deep.x:g} {deep.values['rbias2'].text()} vs D "
                      f"{shallow.x:g} {shallow.values['rbias2'].text()}")
    text = "; ".join(detail) or "no scene with two depths"
    if signs and 2 * signs.count(1) > len(signs):
        return Verdict(claim=claim, verdict="holds", reason=f"lower, intervals apart; {text}")
    if -1 in signs and 1 not in signs:
        return Verdict(claim=claim, verdict="does not hold",
                       reason=f"higher, intervals apart, and lower on no scene; {text}")
    return Verdict(claim=claim, verdict="not comparable",
                   reason=f"intervals overlap on most scenes; {text}")


def draw(reproduction: Reproduction, path: Path) -> Path:
    return plot_panels(reproduction, [Panel(key, label, log_y=key != "ms_per_frame")
                                      for key, label in QUANTITIES.items()], path, log_x=False)


FIGURE = register(FigureSpec("nirc", "fig15", "Hidden layers D of the cache against its "
                             "error (rBias² with every path ended into the cache at v1) and "
                             "time per frame", {"quick": QUICK, "full": FULL}, measure, draw))
