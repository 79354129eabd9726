"""[BM25] Fig. 7 (Sec. 4.1.1): ReSTIR DI with the (clustered) neural visibility cache's
initial candidates against ReSTIR's power-sampled ones, after a disocclusion event.

Ours: `restir-di` and `restir-nvc` on `many-lights-300` (300 lights, so the cache
clusters them, paper Sec. 3.4) with a static camera and one disocclusion at
:func:`disocclusion_frame` (an animation's ``disocclusions``: every pixel's motion
vector is invalid there, so temporal reuse starts afresh while the image stays the
same; docs/animation.md). MRSE and HDR-FLIP of every frame against the (one)
reference, seed means with 95 % Student-t intervals (jobs.protocol.animation), and
the frames each method takes to recover after the event with their bootstrap
interval (metrics.recovery). The claim is judged at the disocclusion frame, where
neither method has temporal history, by HDR-FLIP: the cache's candidates must lower
it beyond both intervals (:func:`verdicts`). Not by MRSE: at these sizes a few
pixels that partly cover one of the small lights make it heavy-tailed (seed-mean
MRSE 2-60 from frame to frame of one run, intervals wider than the values).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jobs.reproduce.animated import curve_point, ms_per_frame, recovery_estimate, stored_run
from jobs.reproduce.papers import paper_data
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Budget, Context, FigureSpec, register
from jobs.reproduce.results import Estimate, Point, Reproduction, Verdict
from renderers.scenes.animation import Animation

SCENE = "many-lights-300"
#: (series, method); both at their defaults (restir-nvc clusters the 300 lights).
SERIES = (("ReSTIR", "restir-di"), ("ReSTIR + NVC", "restir-nvc"))
QUANTITIES = {"mrse": "MRSE (seed mean)", "flip": "HDR-FLIP (seed mean)",
              "recovery": "frames to recover after the disocclusion",
              "ms_per_frame": "ms per frame",
              "frame_time_increase": "frame time over ReSTIR's (%)"}
CLAIM = "NVC initial candidates reduce the noise after a disocclusion"

QUICK_WHY = ("--quick: 16x16, K = 4 seeds of F = 12 frames, the disocclusion at frame 6, "
             "one reference at 256 spp (the camera does not move): 2 series x 4 seeds")
FULL_WHY = ("--full: 32x32, K = 8 seeds of F = 24 frames, the disocclusion at frame 12, "
            "reference at 1024 spp")
QUICK = Budget(resolution=16, seeds=4, frames=12, ref_spp=256, grid_preset="—", why=QUICK_WHY)
FULL = Budget(resolution=32, seeds=8, frames=24, ref_spp=1024, grid_preset="—", why=FULL_WHY)


def disocclusion_frame(frames: int) -> int:
    """The event halfway through the run: as many frames of history before it as after."""
    return max(frames // 2, 1)


def disocclusion(frames: int) -> Animation:
    return Animation(disocclusions=[disocclusion_frame(frames)])


def render_series(ctx: Context, method: str) -> Any:
    """The stored run of ``method`` with the disocclusion at the budget (one stored with
    the same spec is read back, not rendered again)."""
    from jobs.protocol.spec import ReferenceSpec, RenderSpec

    b = ctx.budget
    spec = RenderSpec(scene=SCENE, method=method, resolution=b.resolution, frames=b.frames,
                      seeds=b.seeds, reference=ReferenceSpec(spp=b.ref_spp),
                      animation=disocclusion(b.frames))
    return stored_run(ctx, spec)


def measure(ctx: Context) -> Reproduction:
    b = ctx.budget
    change = disocclusion_frame(b.frames)
    points: list[Point] = []
    at_change: dict[str, Estimate] = {}
    ms: dict[str, float | None] = {}
    for series, method in SERIES:
        run = render_series(ctx, method)
        animation = run.metrics["animation"]
        curve = [curve_point(SCENE, series, frame, animation) for frame in range(b.frames)]
        at_change[series] = curve[change].values["flip"]
        points += curve
        ms[series] = ms_per_frame(run)
        points.append(Point(scene=SCENE, series=series, run_id=run.id,
                            values={"recovery": recovery_estimate(animation, change),
                                    "ms_per_frame": Estimate(value=ms[series])}))
    points[-1] = points[-1].model_copy(update={
        "values": {**points[-1].values, "frame_time_increase": time_increase(*ms.values())},
        "paper": {v.quantity: v.value for v in paper_data("nvc").of("fig7")[0]}})
    return Reproduction(
        paper="nvc", figure="fig7", title="[BM25] Fig. 7: ReSTIR with NVC initial candidates "
                                          "after a disocclusion",
        mode="", settings={"resolution": f"{b.resolution}x{b.resolution}", "seeds K": b.seeds,
                           "frames F": b.frames, "disocclusion at frame": change,
                           "reference spp": b.ref_spp, "why": b.why},
        x_label="frame", quantities=QUANTITIES, points=points,
        verdicts=verdicts(at_change, change, b),
        notes=["our scene is the project's many-lights-300 (300 small lights), not the "
               "paper's Subway with 60k lights",
               "the disocclusion invalidates every pixel's motion vector with the camera "
               "still, so the reference is one image; the paper's event comes from motion",
               "rows without a frame: each method's frames to recover after the event and "
               "its median ms per frame on this shared 2-core CPU (restir-nvc's includes "
               "its cache's training step); the paper's 5 % is on a GPU over 1024 frames "
               "of a flying camera"])


def time_increase(plain_ms: float | None, nvc_ms: float | None) -> Estimate:
    """restir-nvc's frame time over restir-di's, in percent (no interval: one median
    frame time per run)."""
    if plain_ms is None or nvc_ms is None or not plain_ms > 0:
        return Estimate(value=None, note="no frame time")
    return Estimate(value=100.0 * (nvc_ms / plain_ms - 1.0))


def verdicts(at_change: dict[str, Estimate], change: int, budget: Budget) -> list[Verdict]:
    """Holds when restir-nvc's FLIP interval at the disocclusion frame lies wholly below
    restir-di's; does not hold when its mean is not below; else (lower but overlapping)
    not comparable at this K."""
    plain, nvc = (at_change[series] for series, _ in SERIES)
    reason = (f"HDR-FLIP at the disocclusion frame {change}: ReSTIR {plain.text()}, ReSTIR + NVC "
              f"{nvc.text()}; {budget.resolution}x{budget.resolution}, K = {budget.seeds}")
    if plain.value is None or nvc.value is None:
        verdict = "not comparable"
    elif nvc.ci95 and plain.ci95 and nvc.ci95[1] < plain.ci95[0]:
        verdict = "holds"
    elif nvc.value >= plain.value:
        verdict = "does not hold"
    else:
        verdict = "not comparable"
    return [Verdict(claim=CLAIM, verdict=verdict, reason=reason)]


def draw(reproduction: Reproduction, path: Path) -> Path:
    return plot_panels(reproduction, [Panel("mrse", "MRSE per frame"),
                                      Panel("flip", "HDR-FLIP per frame", log_y=False)],
                       path, log_x=False)


FIGURE = register(FigureSpec("nvc", "fig7", "restir-di against restir-nvc after a disocclusion "
                             "in every pixel: MRSE and FLIP per frame, frames to recover",
                             {"quick": QUICK, "full": FULL}, measure, draw))
