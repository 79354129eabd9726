"""[DKHD24] Fig. 9: the neural samples split between the first and second vertex
(N_c¹, N_c²) at a fixed total, paths of at most 5 vertices, no Russian roulette.

Ours: unbiased `nirc` (two-level Monte Carlo, one N_c per vertex: ``nc = [N_c¹, N_c²]``)
with N_c¹ + N_c² = :data:`TOTAL`, ``max_depth`` :data:`MAX_DEPTH` and roulette off
(``rr_survival`` 1), each split a point of the generic parameter sweep (one value of
``pretrain_frames``, as Fig. 6's series are); MRSE, FLIP and rVar with their intervals
and the time per frame, against N_c¹."""

from __future__ import annotations

from pathlib import Path

from jobs.reproduce.measure import frame_ms, metric, sweep
from jobs.reproduce.nirc_fig7 import flip, interval_order
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Budget, Context, FigureSpec, register
from jobs.reproduce.results import Point, Reproduction, Verdict

SCENES = ("cornell-box", "white-room")
TOTAL = 8
MAX_DEPTH = 5
PRETRAIN_PER_FRAME = 2
QUANTITIES = {"mrse": "MRSE", "flip": "FLIP", "rvar": "rVar", "ms_per_frame": "ms per frame"}

QUICK_WHY = ("--quick: 16x16, K = 3 seeds of F = 4 frames after 8 pre-training frames, "
             "N_c¹ 2, 4, 6 of 8")
FULL_WHY = "--full: 64x64, K = 4, F = 64 after 128 pre-training frames, N_c¹ 1-7 of 8"
QUICK = Budget(resolution=16, seeds=3, frames=4, ref_spp=256, grid_preset="—", why=QUICK_WHY,
               values=(2.0, 4.0, 6.0))
FULL = Budget(resolution=64, seeds=4, frames=64, ref_spp=1024, grid_preset="—",
              why=FULL_WHY, values=(1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0))


def measure(ctx: Context) -> Reproduction:
    b = ctx.budget
    points: list[Point] = []
    for scene in SCENES:
        for first in b.values:
            params = {"estimator": "unbiased", "nc": [int(first), TOTAL - int(first)],
                      "rr_survival": 1.0}
            [(row, run)] = sweep(ctx, scene, "nirc", "pretrain_frames",
                                 [PRETRAIN_PER_FRAME * b.frames], params, max_depth=MAX_DEPTH)
            points.append(Point(scene=scene, series=scene, x=float(first), run_id=row.id,
                                values={"mrse": metric(row, "mrse"), "flip": flip(run, row.flip),
                                        "rvar": metric(row, "rvar"),
                                        "ms_per_frame": frame_ms(row)}))
    return Reproduction(
        paper="nirc", figure="fig9", title="[DKHD24] Fig. 9: N_c split between the first and "
                                           "second vertex",
        mode="", settings={"resolution": f"{b.resolution}x{b.resolution}", "seeds K": b.seeds,
                           "frames F": b.frames, "N_c¹ + N_c²": TOTAL,
                           "max depth": MAX_DEPTH, "roulette": "off", "why": b.why},
        x_label=f"N_c¹ (N_c² = {TOTAL} - N_c¹)", quantities=QUANTITIES, points=points,
        verdicts=[verdict(points)],
        notes=["unbiased NIRC: the estimator with one N_c per vertex",
               "Sponza and Country Kitchen are not built in: cornell-box and white-room, "
               "two indoor scenes of different materials, stand for them"])


def best_splits(points: list[Point], scene: str) -> set[float]:
    """The N_c¹ of ``scene`` whose MRSE is not told apart from the lowest: its interval
    overlaps the interval of the point of lowest MRSE."""
    found = [(p.x, p.values["mrse"]) for p in points if p.scene == scene
             and p.x is not None and p.values["mrse"].value is not None]
    if not found:
        return set()
    _x, lowest = min(found, key=lambda item: item[1].value or 0.0)
    return {x for x, mrse in found if mrse is lowest or interval_order(mrse, lowest) == 0}


def verdict(points: list[Point]) -> Verdict:
    """Scene-dependent optimum: holds when the scenes' sets of best splits are disjoint;
    does not hold when every scene's best set is the same single split; else not
    comparable (the intervals cannot tell)."""
    claim = "the best N_c split depends on the scene"
    best = {scene: best_splits(points, scene) for scene in SCENES}
    detail = "; ".join(f"{scene}: best N_c¹ {sorted(int(x) for x in found) or 'none'}"
                       for scene, found in best.items())
    sets = list(best.values())
    if any(not s for s in sets):
        return Verdict(claim=claim, verdict="not comparable", reason=f"a scene lacks points; "
                                                                     f"{detail}")
    if all(a.isdisjoint(b) for i, a in enumerate(sets) for b in sets[i + 1:]):
        return Verdict(claim=claim, verdict="holds",
                       reason=f"the scenes' best splits differ, intervals apart; {detail}")
    if all(len(s) == 1 for s in sets) and len({frozenset(s) for s in sets}) == 1:
        return Verdict(claim=claim, verdict="does not hold",
                       reason=f"one split is best on every scene, intervals apart; {detail}")
    return Verdict(claim=claim, verdict="not comparable",
                   reason=f"the best splits overlap between scenes within the intervals; "
                          f"{detail}")


def draw(reproduction: Reproduction, path: Path) -> Path:
    return plot_panels(reproduction, [Panel(key, label, log_y=key != "ms_per_frame")
                                      for key, label in QUANTITIES.items()], path, log_x=False)


FIGURE = register(FigureSpec("nirc", "fig9", "Neural samples split between the first and "
                             "second vertex at a fixed total (8), up to 5 vertices, no "
                             "roulette: MRSE, FLIP, rVar and time against N_c¹",
                             {"quick": QUICK, "full": FULL}, measure, draw))
