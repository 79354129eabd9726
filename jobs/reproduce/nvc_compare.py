"""[BM25] Figs. 1 and 9: screen-space ReSTIR against neural light sampling (and, in
Fig. 1, Neural DI) after training, at equal samples (Fig. 1: one sample per pixel
each) or at equal time (Fig. 9: ReSTIR's spp calibrated to neural light sampling's
frame time, docs/protocol.md "Equal time").

Ours: `restir-di`, `nvc-lights` at max_depth 2 (direct light at primary hits, the
quantity `restir-di` and `neural-di` estimate) and `neural-di` on `many-lights`
(32 lights, standing in for the paper's Kitchen and Sponza), the caches pre-trained
for :data:`PRETRAIN_PER_FRAME` x F frames before the F scored frames. HDR-FLIP of
every frame against the reference, the seeds' mean with its Student-t interval, and
the median frame time; both as ratios to ReSTIR's. The runs are stored under one key
for both figures (:data:`RUN_KEY`), so Fig. 9 reads back Fig. 1's NVC lights run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jobs.reproduce.animated import stored_run
from jobs.reproduce.measure import budget_settings
from jobs.reproduce.papers import paper_data
from jobs.reproduce.plot import Panel, plot_panels
from jobs.reproduce.registry import Budget, Context
from jobs.reproduce.results import Estimate, Point, Reproduction, Verdict

SCENE = "many-lights"
RESTIR, NVC, NEURAL_DI = "ReSTIR", "NVC lights", "Neural DI"
#: (series, method, parameters): direct light at primary hits for all three.
SERIES = ((RESTIR, "restir-di", {}), (NVC, "nvc-lights", {"max_depth": 2}),
          (NEURAL_DI, "neural-di", {}))
#: Training frames before the scored ones, per scored frame ("after training": the
#: cache's learning rate decays over 200 steps, docs of nvc-lights).
PRETRAIN_PER_FRAME = 16
QUANTITIES = {"flip": "HDR-FLIP (seed mean)", "flip_ratio": "FLIP / ReSTIR's",
              "ms_per_frame": "ms per frame", "time_ratio": "frame time / ReSTIR's",
              "spp": "spp"}
FLIP_NOTE = "FLIP: 95 % Student-t interval over the K seeds' HDR-FLIP"
#: ReSTIR's spp candidates at equal time, bounded: a calibration capped at the largest
#: gives ReSTIR less than equal time, which still decides "does not hold" when ReSTIR's
#: FLIP is the lower one (:func:`equal_time_verdict`); timing more candidates would not.
RESTIR_SPP = [1, 2, 4, 8, 16]
#: The stored runs' key shared by Figs. 1 and 9 (jobs/reproduce/animated.py, stored_run).
RUN_KEY = "nvc-fig1-fig9"

QUICK = Budget(resolution=32, seeds=4, frames=4, ref_spp=1024, grid_preset="—",
               why="--quick: 32x32, K = 4 seeds of F = 4 one-spp frames after 64 training "
                   "frames, reference 1024 spp: minutes on 2 cores")
FULL = Budget(resolution=128, seeds=8, frames=8, ref_spp=4096, grid_preset="—",
              why="--full: 128x128 (the training batch is a smaller share of a frame's "
                  "work), K = 8, F = 8; about an hour on one GPU worker")


def render(ctx: Context, method: str, params: dict[str, Any],
           budget_ms: float | None = None) -> Any:
    """The stored run of ``method`` at the context's budget, its spp calibrated to
    ``budget_ms`` per frame when given (one stored under :data:`RUN_KEY` with the same
    spec is read back)."""
    from jobs.protocol.spec import ReferenceSpec, RenderSpec, TimeBudget

    b = ctx.budget
    time_budget = None if budget_ms is None else TimeBudget(
        ms=budget_ms, candidates=RESTIR_SPP, allow_loaded=True, tolerance_ms=0.05 * budget_ms)
    spec = RenderSpec(scene=SCENE, method=method, params=params, resolution=b.resolution,
                      frames=b.frames, seeds=b.seeds, reference=ReferenceSpec(spp=b.ref_spp),
                      time_budget=time_budget)
    return stored_run(ctx, spec, RUN_KEY)


def flip(run: Any) -> Estimate:
    """The seeds' mean HDR-FLIP with its interval over the seeds."""
    from metrics.bias_intervals import bias_interval

    per_seed = [float(s.metrics["flip_hdr"]) for s in run.seed_results
                if "flip_hdr" in s.metrics]
    if not per_seed:
        return Estimate(value=None, note="no FLIP stored")
    interval, note = bias_interval(per_seed, FLIP_NOTE)
    return Estimate(value=sum(per_seed) / len(per_seed), ci95=interval, note=note)


def ms_per_frame(run: Any) -> float | None:
    seconds = (run.timings or {}).get("seconds_per_frame")
    return None if seconds is None else 1e3 * float(seconds)


def ratio(value: float | None, base: float | None) -> Estimate:
    """``value`` / ``base`` (no interval: FLIP's intervals are those of the rows)."""
    if value is None or base is None or not base > 0:
        return Estimate(value=None, note="no ratio: a value is missing")
    return Estimate(value=value / base)


def paper_values(figure: str) -> dict[str, dict[str, float]]:
    """The paper's frame-time ratios (Fig. 1's ms) and FLIP ratio per series."""
    values, _claims = paper_data("nvc").of("fig1")
    ms = {v.series: v.value for v in values if v.quantity == "frame_time"}
    reduction = next(v.value for v in paper_data("nvc").of(figure)[0]
                     if v.quantity == "flip_reduction")
    by_series = {RESTIR: "restir-di", NVC: "nvc-lights", NEURAL_DI: "neural-di"}
    out = {series: {"ms_per_frame": ms[key], "time_ratio": ms[key] / ms["restir-di"]}
           for series, key in by_series.items()}
    out[NVC]["flip_ratio"] = 1.0 - reduction / 100.0
    if figure != "fig1":   # Fig. 9 is at equal time: its times are not the paper's Fig. 1's
        out = {series: {k: v for k, v in values_.items() if k == "flip_ratio"}
               for series, values_ in out.items()}
    return out


def measure_comparison(ctx: Context, figure: str, equal_time: bool) -> Reproduction:
    """Fig. 1 (``equal_time`` False: 1 spp each) or Fig. 9 (ReSTIR at NVC lights' time)."""
    b = ctx.budget
    pretrain = PRETRAIN_PER_FRAME * b.frames
    runs: dict[str, Any] = {}
    series = SERIES if not equal_time else SERIES[1::-1]   # Fig. 9: NVC's time first
    for name, method, params in series:
        extra = {} if method == "restir-di" else {"pretrain_frames": pretrain}
        budget_ms = ms_per_frame(runs[NVC]) if equal_time and name == RESTIR else None
        runs[name] = render(ctx, method, {**params, **extra}, budget_ms)
    base_flip, base_ms = flip(runs[RESTIR]).value, ms_per_frame(runs[RESTIR])
    paper = paper_values(figure)
    points = []
    for index, (name, _method, _params) in enumerate(s for s in SERIES if s[0] in runs):
        run = runs[name]
        estimate = flip(run)
        points.append(Point(scene=SCENE, series=name, x=float(index), run_id=run.id,
                            values={"flip": estimate,
                                    "flip_ratio": ratio(estimate.value, base_flip),
                                    "ms_per_frame": Estimate(value=ms_per_frame(run)),
                                    "time_ratio": ratio(ms_per_frame(run), base_ms),
                                    "spp": Estimate(value=float(run.spp))},
                            paper=paper[name]))
    calibration = (runs[RESTIR].metrics or {}).get("calibration") if equal_time else None
    notes = ["many-lights (32 lights) stands in for the paper's Kitchen and Sponza (32 "
             "lights each)",
             "frame times on this shared 2-core CPU: the caches' training step (8192 "
             "points x 32 shadow rays) is a far larger share of a frame at this image "
             "size than at the paper's 1920x1080, so time ratios are not the paper's",
             f"the caches are pre-trained for {pretrain} frames before the F scored frames"]
    if equal_time:
        notes.append(f"ReSTIR's spp calibrated to NVC lights' {ms_per_frame(runs[NVC]):.1f} ms "
                     f"per frame, 5 % tolerance: chose {runs[RESTIR].spp}"
                     + ("" if not calibration else
                        f" (flags: {', '.join(calibration.get('reasons') or []) or 'none'})"))
    title = ("[BM25] Fig. 9: ReSTIR against neural light sampling at equal time" if equal_time
             else "[BM25] Fig. 1: ReSTIR, neural light sampling and Neural DI at 1 spp")
    return Reproduction(
        paper="nvc", figure=figure, title=title, mode="",
        settings=budget_settings(ctx, **{"pretrain frames": pretrain,
                                         "equal": "time" if equal_time else "samples (1 spp)"}),
        x_label="row", quantities=QUANTITIES, points=points, notes=notes,
        verdicts=verdicts(points, figure, calibration or {}))


def interval_below(a: Estimate, b: Estimate) -> str:
    """'holds' when ``a``'s 95 % interval lies wholly below ``b``'s, 'does not hold' when
    ``a``'s mean is not below ``b``'s, else 'not comparable' (lower, intervals overlap)."""
    if a.value is None or b.value is None:
        return "not comparable"
    if a.ci95 and b.ci95 and a.ci95[1] < b.ci95[0]:
        return "holds"
    return "does not hold" if a.value >= b.value else "not comparable"


def equal_time_verdict(nvc: Estimate, restir: Estimate,
                       calibration: dict[str, Any]) -> tuple[str, str]:
    """:func:`interval_below` of NVC lights' FLIP against ReSTIR's at equal time, and what
    bounds it. ReSTIR's calibration (its stored record) ``capped`` (its largest spp fits:
    ReSTIR got less than equal time) can only tell "does not hold", since more samples
    would lower ReSTIR's FLIP further; not ``fits`` (even its least spp is over the
    time: more than equal time) only "holds"; the other outcome is "not comparable"."""
    verdict = interval_below(nvc, restir)
    if calibration.get("capped"):
        decides = "does not hold"
        bound = f"; ReSTIR capped at {calibration['chosen']} spp, less than equal time"
    elif calibration and not calibration.get("fits", True):
        decides = "holds"
        bound = f"; ReSTIR's least {calibration['chosen']} spp is over equal time"
    else:
        return verdict, ""
    return (verdict if verdict == decides else "not comparable"), bound


def verdicts(points: list[Point], figure: str,
             calibration: dict[str, Any]) -> list[Verdict]:
    """Fig. 1: NVC lights' FLIP below ReSTIR's, Neural DI's below both; Fig. 9: NVC
    lights' below ReSTIR's at equal time (:func:`interval_below`, bounded by ReSTIR's
    ``calibration``: :func:`equal_time_verdict`)."""
    flips = {p.series: p.values["flip"] for p in points}
    size = f"{SCENE}, {len(points)} series"

    def text(*names: str) -> str:
        return "; ".join(f"{n} {flips[n].text()}" for n in names) + f" ({size})"

    if figure == "fig9":
        verdict, bound = equal_time_verdict(flips[NVC], flips[RESTIR], calibration)
        return [Verdict(claim="NVC lights' FLIP below ReSTIR's at equal time", verdict=verdict,
                        reason=f"HDR-FLIP at equal time: {text(RESTIR, NVC)}{bound}")]
    neural = [interval_below(flips[NEURAL_DI], flips[other]) for other in (RESTIR, NVC)]
    worst = next((v for v in ("does not hold", "not comparable") if v in neural), "holds")
    return [Verdict(claim="NVC lights' FLIP below ReSTIR's at 1 spp",
                    verdict=interval_below(flips[NVC], flips[RESTIR]),
                    reason=f"HDR-FLIP at 1 spp: {text(RESTIR, NVC)}"),
            Verdict(claim="Neural DI's FLIP below ReSTIR's and NVC lights'", verdict=worst,
                    reason=f"HDR-FLIP at 1 spp: {text(RESTIR, NVC, NEURAL_DI)}")]


def draw(reproduction: Reproduction, path: Path) -> Path:
    return plot_panels(reproduction, [Panel("flip", "HDR-FLIP", log_y=False),
                                      Panel("time_ratio", "frame time / ReSTIR's",
                                            log_y=False)], path, log_x=False)
