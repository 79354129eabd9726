"""[DKHD24] Fig. 4: FLIP against training epochs of the biased (Eq. 13) and unbiased
(Eq. 10-12) NIRC estimators with N_c = 4, N_r = 1, the cache trained with L_V (Eq. 16)
or L2 (Eq. 17); we add the relative L2 (Eq. 18) the method trains with by default.

Ours: `nirc` at every series' parameters, swept over ``pretrain_frames`` (training
epochs before the F rendered frames, each of which trains once more): a point at x
epochs is a render whose cache trained x + F times from scratch, its FLIP that of the
F-frame image against the reference, its interval over the K seeds. ``--quick`` draws
the paper's two losses only (:func:`losses`). L_V's F_r is the
mean residual of :data:`RESIDUAL_SAMPLES` training paths through one film position
(the cache's ``loss.group_size``; the paper says only "multiple samples"). Every series
records training data at the first vertex only (``record_depth`` 1), which L_V needs
(the only vertex the group shares), so that the losses differ in nothing else."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jobs.reproduce.measure import sweep
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Budget, Context, FigureSpec, register
from jobs.reproduce.results import Estimate, Point, Reproduction, Verdict, apart

SCENES = ("cornell-box", "door")
ESTIMATORS = ("biased", "unbiased")
#: The losses by the `nirc` parameter's value, as the table names them: the paper's two,
#: then ours, relative L2.
LOSSES = {"variance": "L_V", "l2": "L2", "relative-l2": "rel. L2"}
PAPER_LOSSES = ("variance", "l2")
#: F_r's sample count for L_V: training paths per first vertex.
RESIDUAL_SAMPLES = 8
QUANTITIES = {"flip": "FLIP (F-frame image)"}

QUICK_WHY = ("--quick: 16x16, K = 3, F = 2 frames, epochs 0/3/10 before them (x = 2, 5, 12: "
             "log-spaced, ratios 2.4-2.5), the paper's losses L_V and L2 only: 2 scenes x 4 "
             "series x 3 points x 3 seeds = 72 renders, each training from scratch; FLIP "
             "at 16x16 is coarse (its filters span several pixels), so compare series, "
             "not the paper's numbers")
FULL_WHY = ("--full: 32x32, K = 6, F = 4 frames, epochs 0-120, relative L2 besides: the "
            "paper trains for hundreds of epochs at 1080p on a GPU, out of reach here")
QUICK = Budget(resolution=16, seeds=3, frames=2, ref_spp=512, grid_preset="—",
               why=QUICK_WHY, values=(0, 3, 10))
FULL = Budget(resolution=32, seeds=6, frames=4, ref_spp=2048, grid_preset="—",
              why=FULL_WHY, values=(0, 4, 12, 28, 60, 120))


def losses(budget: Budget) -> tuple[str, ...]:
    """The losses drawn at ``budget``: --quick the paper's (the claims compare L_V with
    L2), --full relative L2 besides."""
    return PAPER_LOSSES if budget == QUICK else tuple(LOSSES)


def series_params(estimator: str, loss: str) -> dict[str, Any]:
    """`nirc` parameters of one series: N_c = 4 (N_r = 1 for the unbiased estimator)."""
    params: dict[str, Any] = {"estimator": estimator, "nc": [4], "loss": loss,
                              "record_depth": 1}
    if loss == "variance":
        params["cache"] = {"loss": {"group_size": RESIDUAL_SAMPLES}}
    return params


def series_name(estimator: str, loss: str) -> str:
    return f"{estimator}, {LOSSES[loss]}"


def measure(ctx: Context) -> Reproduction:
    points: list[Point] = []
    for scene in SCENES:
        for estimator in ESTIMATORS:
            for loss in losses(ctx.budget):
                for row, run in sweep(ctx, scene, "nirc", "pretrain_frames",
                                       [int(v) for v in ctx.budget.values],
                                       series_params(estimator, loss)):
                    points.append(Point(scene=scene, series=series_name(estimator, loss),
                                        x=float(row.value) + ctx.budget.frames,
                                        run_id=row.id, values={"flip": flip(run)}))
    b = ctx.budget
    return Reproduction(
        paper="nirc", figure="fig4", title="[DKHD24] Fig. 4: FLIP per training epoch, "
                                           "L_V against L2",
        mode="", settings={"resolution": f"{b.resolution}x{b.resolution}", "seeds K": b.seeds,
                           "frames F": b.frames, "reference spp": b.ref_spp,
                           "N_c": 4, "N_r": 1, "F_r samples": RESIDUAL_SAMPLES,
                           "record depth": 1, "why": b.why},
        x_label="training epochs", quantities=QUANTITIES, points=points,
        verdicts=verdicts(points),
        notes=["our scenes are the project's built-in cornell-box and door, not the paper's",
               "an epoch is one frame's training: 4 Adam steps (the cache preset's)",
               "L_V groups 8 training paths per film position: the same path count sees "
               "1/8 as many shading points as the L2 losses",
               "the paper's plot cannot be read from its text copy: its claims are checked, "
               "not its numbers"])


FLIP_NOTE = ("FLIP: HDR-FLIP mean over pixels of each seed's F-frame image, the mean over "
             "the K seeds; 95 % interval: Student t (K-1 degrees of freedom) over the seeds")


def flip(run: Any) -> Estimate:
    """The K seeds' mean FLIP with its interval over them (:data:`FLIP_NOTE`)."""
    from metrics.bias_intervals import bias_interval

    per_seed = [float(seed.metrics.get("flip_hdr", "nan")) for seed in run.seed_results]
    interval, note = bias_interval(per_seed, FLIP_NOTE)
    return Estimate(value=sum(per_seed) / len(per_seed), ci95=interval, note=note)


def _last(points: list[Point], scene: str, series: str) -> Estimate | None:
    members = [p for p in points if p.scene == scene and p.series == series]
    return max(members, key=lambda p: p.x or 0.0).values["flip"] if members else None


def verdicts(points: list[Point]) -> list[Verdict]:
    """The two claims of Fig. 4's caption, at the last epoch of each scene."""
    harm, diverge = [], []
    for scene in SCENES:
        lv = _last(points, scene, series_name("biased", "variance"))
        l2 = _last(points, scene, series_name("biased", "l2"))
        if lv is not None and l2 is not None:
            harm.append((scene, apart(lv, l2), lv.text(), l2.text()))
        for estimator in ESTIMATORS:
            name = series_name(estimator, "variance")
            members = sorted((p for p in points if p.scene == scene and p.series == name),
                             key=lambda p: p.x or 0.0)
            if len(members) >= 2:
                best = min(members[:-1], key=lambda p: p.values["flip"].value or 1e9)
                diverge.append((scene, estimator, apart(members[-1].values["flip"],
                                                         best.values["flip"])))
    return [_verdict("L_V hurts the biased estimator (last epoch, biased L_V against biased L2)",
                     [s for s, sign, *_ in harm if sign > 0],
                     [s for s, sign, *_ in harm if sign < 0], len(harm),
                     "; ".join(f"{s}: L_V {a} vs L2 {b}" for s, _, a, b in harm)),
            _verdict("L_V diverges in training (its FLIP at the last epoch above its best "
                     "earlier epoch)",
                     [f"{s} {e}" for s, e, sign in diverge if sign > 0],
                     [f"{s} {e}" for s, e, sign in diverge if sign < 0], len(diverge),
                     "intervals over seeds compared")]


def _verdict(claim: str, agree: list[str], disagree: list[str], cases: int,
             detail: str) -> Verdict:
    if cases == 0:
        return Verdict(claim=claim, verdict="not comparable", reason="no points measured")
    if agree and not disagree:
        return Verdict(claim=claim, verdict="holds",
                       reason=f"intervals apart in {', '.join(agree)} of {cases}; {detail}")
    if disagree and not agree:
        return Verdict(claim=claim, verdict="does not hold",
                       reason=f"the opposite, intervals apart, in {', '.join(disagree)}; "
                              f"{detail}")
    return Verdict(claim=claim, verdict="not comparable",
                   reason=f"95 % intervals overlap or disagree between cases ({detail})")


def draw(reproduction: Reproduction, path: Path) -> Path:
    return plot_panels(reproduction, [Panel("flip", f"{scene}: FLIP", log_y=False, scene=scene)
                                      for scene in SCENES], path, log_x=False)


FIGURE = register(FigureSpec("nirc", "fig4", "FLIP per training epoch of the biased and "
                             "unbiased estimators (N_c 4, N_r 1) trained with L_V, L2 and "
                             "relative L2, on cornell-box and door", {"quick": QUICK,
                                                                      "full": FULL},
                             measure, draw))
