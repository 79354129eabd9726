"""[DKHD24] Fig. 6 (Sec. 6.1): the relative variance of the residual estimator,
V_rel(<F_r>), of the control variates the paper compares (per-pixel SH and vMF, NCV)
and of the neural caches (SS NIRC, unbiased NIRC with 6 hidden layers), and
the fitted integrands: at the first hits of three pixels of cornell-box, the reference
integrand f = L_ind f_s cos over the sphere of directions and SH's, vMF's, NCV's and
NIRC's fit of it after the F frames, drawn as integrands.png beside the figure
(jobs/reproduce/nirc_fig6_integrands.py).

Ours: each method at its equal-memory preset where it has one (SH 5 bands, 75 floats
per pixel; vMF 11 lobes, 77; SS NIRC's latent table, 74), NCV and NIRC at their
defaults (networks shared by every pixel: their floats per pixel are the parameters
over the pixels, shown), on every scene; V_rel per seed from an untimed probe with the
final model or cache after F frames (docs/metrics.md), its interval over the K seeds,
and the median time per frame. The EMA curves: V_rel after every training frame of NCV
and NIRC, one seed per scene (jobs/reproduce/nirc_fig6_curves.py), over
:data:`CURVE_FRAMES` frames (the paper's 4000 with --full), drawn as ema.png beside the
figure."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jobs.reproduce import nirc_fig6_curves as curves
from jobs.reproduce import nirc_fig6_integrands as integrands
from jobs.reproduce.measure import frame_ms, sweep
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Budget, Context, FigureSpec, register
from jobs.reproduce.results import Estimate, Point, Reproduction, Verdict

SCENES = ("cornell-box", "door", "white-room", "sky")
#: (series, method, its parameters, a parameter at its default: the sweep's single point)
#: The control variates pre-train 0 frames, as the caches do (a sweep's point otherwise
#: pre-trains ``train_frames``, 100 by default: 104 frames against the caches' 4).
SERIES = (
    ("SH", "cv-sh", {"pretrain_frames": 0}, "uniform_fraction", 0.25),
    ("vMF", "cv-vmf", {"pretrain_frames": 0}, "uniform_fraction", 0.25),
    ("NCV", "ncv", {"pretrain_frames": 0}, "uniform_fraction", 0.25),
    ("SS NIRC", "ss-nirc", {}, "pretrain_frames", 0),
    ("NIRC", "nirc", {"estimator": "unbiased", "cache": {"mlp": {"hidden_layers": 6}}},
     "pretrain_frames", 0),
)
#: Equal memory (about the paper's 75 floats per pixel) for the two neural models, by image
#: size: their defaults hold 1.6 M (NCV) and 1.3 M (NIRC) parameters, about 1,560 and 1,270
#: floats a pixel at 32x32, and NCV's paper-sized flows alone (303 k) would need about
#: 100x100 pixels. Small networks instead, their floats measured (docs/reproduce.md):
#: at 32x32 (--full) NCV 66.0 (flows of 16 bins, one hidden layer of 16; hash grid 8
#: levels x 2^11) and NIRC 66.3 (6 hidden layers of 16; 8 levels x 2^12). --quick (16x16)
#: has none: they judge no claim and were a quarter of its time (docs/reproduce.md).
EQUAL_MEMORY = {
    32: ({"flow": {"bins": 16, "blob_bins": 8, "width": 16, "hidden_layers": 1},
          "normal_bins": 2, "integral_width": 16, "integral_hidden_layers": 2,
          "position": {"n_levels": 8, "log2_hashmap_size": 11, "base_resolution": 4}},
         {"mlp": {"hidden_layers": 6, "width": 16},
          "position": {"n_levels": 8, "log2_hashmap_size": 12}}),
}
EQUAL_LABELS = ("NCV (~75 floats)", "NIRC (~75 floats)")


def equal_memory_series(resolution: int) -> tuple[tuple[Any, ...], ...]:
    """The equal-memory series at an image size (none where no preset is set)."""
    if resolution not in EQUAL_MEMORY:
        return ()
    ncv, nirc = EQUAL_MEMORY[resolution]
    return ((EQUAL_LABELS[0], "ncv", {"pretrain_frames": 0, "ncv": ncv}, "uniform_fraction",
             0.25),
            (EQUAL_LABELS[1], "nirc", {**SERIES[4][2], "cache": {**nirc}}, "pretrain_frames", 0))


QUANTITIES = {"v_rel": "V_rel(<F_r>)", "ms_per_frame": "ms per frame",
              "floats_per_pixel": "floats per pixel", "v_rel_ema": "EMA of V_rel"}
#: The series with an EMA curve: (label, method, its parameters, the frame loop).
CURVES = (("NCV", "ncv", {}, curves.ncv_frames),
          ("NIRC", "nirc", SERIES[4][2], curves.nirc_frames))
#: NIRC's V_rel against NCV's, as the paper states it (1.1-1.32x lower).
PAPER_RATIO = (1.1, 1.32)

QUICK_WHY = ("--quick: 16x16, K = 3 seeds of F = 4 frames (the paper trains for thousands "
             "of frames at 1080p on a GPU): 4 scenes x 5 series x 3 seeds = 60 renders, no "
             "equal-memory series (--full's), EMA curves of 8 frames")
FULL_WHY = "--full: 32x32, K = 4, F = 64 frames: still far below the paper's training"
QUICK = Budget(resolution=16, seeds=3, frames=4, ref_spp=256, grid_preset="—", why=QUICK_WHY)
FULL = Budget(resolution=32, seeds=4, frames=64, ref_spp=1024, grid_preset="—", why=FULL_WHY)

#: Training frames of each EMA curve, by budget (a replaced budget: its frames).
CURVE_FRAMES = {QUICK: 8, FULL: 4000}
CURVE_WHY = ("EMA curves: one seed per scene and method, a residual probe after every "
             "frame; --quick {frames} frames ({seconds:.0f} s of rendering here), --full "
             "4000 as the paper")
EMA_NOTE = (f"EMA (alpha {curves.ALPHA}) of V_rel after each training frame, one seed; "
            "no interval")

INTEGRANDS_NOTE = ("integrands.png: f = L_ind f_s cos at the first hits of three cornell-box "
                   "pixels on a 64x32 lat-long grid of directions in the shading frame "
                   "(reference: {spp} paths a direction), beside SH's, vMF's and NCV's g and "
                   "NIRC's n f_s cos after {frames} training frames; symmetric log colour "
                   "scale per row")
V_REL_NOTE = "V_rel: the K seeds' mean; 95 % interval: log-scale over the seeds (docs/metrics.md)"


def v_rel(run: Any) -> Estimate:
    metrics = run.metrics or {}
    return Estimate(value=metrics.get("v_rel_mean"), ci95=metrics.get("v_rel_ci95"),
                    note=V_REL_NOTE)


def floats_per_pixel(run: Any, pixels: int) -> float | None:
    """The model's floats per pixel as the run stores them (the control variates, SS NIRC,
    NCV), else a network cache's parameters over the pixels."""
    stats = (run.seed_results[0].metrics.get("method_stats") or {}) if run.seed_results else {}
    floats = (stats.get("model") or {}).get("floats_per_pixel")
    if isinstance(floats, dict):
        floats = floats.get("model")
    cache = (stats.get("caches") or {}).get("cache") or {}
    if floats is None and "parameters" in cache:
        floats = cache["parameters"] / pixels
    return None if floats is None else float(floats)


def measure(ctx: Context) -> Reproduction:
    b = ctx.budget
    points: list[Point] = []
    all_series = SERIES + equal_memory_series(b.resolution)
    for scene in SCENES:
        for index, (series, method, params, parameter, value) in enumerate(all_series):
            [(row, run)] = sweep(ctx, scene, method, parameter, [value], params)
            points.append(Point(scene=scene, series=series, x=float(index), run_id=row.id,
                                values={
                "v_rel": v_rel(run),
                "ms_per_frame": frame_ms(row),
                "floats_per_pixel": Estimate(value=floats_per_pixel(run, b.resolution**2))}))
    curve_points, curve_note = ema_points(ctx)
    points += curve_points
    if ctx.progress:
        ctx.progress("integrand images", 0, 1)
    images = integrands.measure_integrands(ctx, {s[0]: s[2] for s in SERIES})
    return Reproduction(
        paper="nirc", figure="fig6", title="[DKHD24] Fig. 6: V_rel(<F_r>) of the control "
                                           "variates and the neural caches",
        mode="", settings={"resolution": f"{b.resolution}x{b.resolution}", "seeds K": b.seeds,
                           "frames F": b.frames, "reference spp": b.ref_spp, "why": b.why},
        x_label="series: " + ", ".join(f"{i} {s[0]}" for i, s in enumerate(all_series))
        + "; EMA rows: training frame",
        quantities=QUANTITIES, points=points, verdicts=verdicts(points, b),
        notes=["our scenes are the project's built-ins, not the paper's",
               "V_rel is the same quantity for every method: the per-pixel sample variance "
               "of the one-sample residual at the primary hit with the final model, over "
               "R² + eps (NIRC: F_r of Eq. 11; control variates: (f - g) / q of Eq. 7)",
               "ms per frame: the median frame on this shared 2-core CPU, not the paper's GPU",
               curve_note, INTEGRANDS_NOTE.format(spp=images.spp, frames=images.frames)],
        images={"integrands": images})


def ema_points(ctx: Context) -> tuple[list[Point], str]:
    """The EMA curves of NCV and NIRC on every scene, as points at the kept frames, and
    the note stating their frames, time and frames without a V_rel."""
    import time

    from jobs.protocol.spec import RenderSpec
    from renderers.methods import parse_params

    b = ctx.budget
    frames = CURVE_FRAMES.get(b, b.frames)
    eps = RenderSpec.model_fields["eps"].default
    points, missing, started = [], 0, time.perf_counter()
    for scene_name in SCENES:
        scene, reference = scene_and_reference(ctx, scene_name)
        for series, method, params, train in CURVES:
            if ctx.progress:
                ctx.progress(f"{series} EMA on {scene_name}", 0, frames)
            curve = curves.v_rel_curve(train, scene, parse_params(method, params),
                                       ("fig6 curve", scene_name, method), frames,
                                       reference.mean, eps)
            averages, skipped = curves.moving_average(curve)
            missing += skipped
            points += [Point(scene=scene_name, series=f"{series} EMA", x=float(t),
                             values={"v_rel_ema": Estimate(value=averages[t - 1],
                                                           note=EMA_NOTE)})
                       for t in curves.kept_frames(frames)]
    note = CURVE_WHY.format(frames=frames, seconds=time.perf_counter() - started)
    if missing:
        note += f"; {missing} frames without a V_rel left out of the averages"
    return points, note


def scene_and_reference(ctx: Context, scene_name: str) -> tuple[Any, Any]:
    """The scene at the budget's size and its reference (the table's, from the store)."""
    from jobs.protocol.references import get_or_render_reference
    from jobs.protocol.scene_store import load_spec_scene
    from jobs.protocol.spec import ReferenceSpec

    scene = load_spec_scene(scene_name, ctx.budget.resolution, ctx.settings)
    return scene, get_or_render_reference(ctx.store, ctx.settings.references_dir, scene,
                                          ReferenceSpec(spp=ctx.budget.ref_spp).settings(-1))


def _get(points: list[Point], scene: str, series: str) -> Estimate | None:
    found = [p.values["v_rel"] for p in points
             if (p.scene, p.series) == (scene, series) and "v_rel" in p.values]
    return found[0] if found and found[0].value is not None else None


def _below(a: Estimate, b: Estimate) -> int:
    """+1 when ``a``'s interval lies below ``b``'s, -1 above, 0 overlapping."""
    if a.ci95 is None or b.ci95 is None:
        return 0
    return 1 if a.ci95[1] < b.ci95[0] else -1 if a.ci95[0] > b.ci95[1] else 0


def verdicts(points: list[Point], budget: Budget) -> list[Verdict]:
    short = (f"F = {budget.frames} training frames, far below the paper's thousands "
             "(its NCV needs about a thousand, NIRC a few hundred)")
    found = []
    for other in ("NCV", "SH", "vMF"):
        signs, detail = [], []
        for scene in SCENES:
            nirc, theirs = _get(points, scene, "NIRC"), _get(points, scene, other)
            if nirc is not None and theirs is not None:
                signs.append(_below(nirc, theirs))
                detail.append(f"{scene}: {nirc.text()} vs {theirs.text()}")
        found.append(_verdict(f"NIRC's V_rel below {other}'s", signs, "; ".join(detail), short))
    ratios = []
    for scene in SCENES:
        nirc, ncv = _get(points, scene, "NIRC"), _get(points, scene, "NCV")
        if nirc is not None and ncv is not None and nirc.value:
            ratios.append(f"{scene} {ncv.value / nirc.value:.2f}x")
    low, high = PAPER_RATIO
    found.append(Verdict(claim=f"NIRC's V_rel {low}-{high}x lower than NCV's",
                         verdict="not comparable",
                         reason=f"{short}; NCV / NIRC here: {', '.join(ratios) or 'none'}"))
    return found


def _verdict(claim: str, signs: list[int], detail: str, short: str) -> Verdict:
    if not signs:
        return Verdict(claim=claim, verdict="not comparable", reason="no points measured")
    if all(s > 0 for s in signs):
        return Verdict(claim=claim, verdict="holds",
                       reason=f"intervals apart on every scene; {detail} ({short})")
    if all(s < 0 for s in signs):
        return Verdict(claim=claim, verdict="does not hold",
                       reason=f"the opposite, intervals apart, on every scene; {detail} "
                              f"({short})")
    return Verdict(claim=claim, verdict="not comparable",
                   reason=f"intervals overlap or the order differs between scenes; {detail} "
                          f"({short})")


def draw(reproduction: Reproduction, path: Path) -> Path:
    """figure.png (V_rel per series) and, beside it, ema.png (the EMA curves) and, when
    measured now (they are not kept in the table), integrands.png."""
    if "integrands" in reproduction.images:
        integrands.draw_integrands(reproduction.images["integrands"],
                                   path.with_name("integrands.png"))
    plot_panels(reproduction.model_copy(update={"x_label": "training frame"}),
                [Panel("v_rel_ema", f"{scene}: EMA of V_rel per frame", scene=scene)
                 for scene in SCENES], path.with_name("ema.png"), log_x=True)
    return plot_panels(reproduction.model_copy(update={"x_label": "series (the table's "
                                                                  "third column)"}),
                       [Panel("v_rel", f"{scene}: V_rel", log_y=True, scene=scene)
                        for scene in SCENES], path, log_x=False)


FIGURE = register(FigureSpec("nirc", "fig6", "V_rel of the residual estimator: SH, vMF and "
                             "neural control variates, SS NIRC and NIRC (6 hidden layers) on "
                             "four scenes, with time per frame and floats per pixel",
                             {"quick": QUICK, "full": FULL}, measure, draw))
