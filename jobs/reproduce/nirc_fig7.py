"""[DKHD24] Fig. 7 (Sec. 6.2): PT at 1 and 2 spp, NRC (biased), NIRC biased and unbiased
at equal time: FLIP, MRSE and compute time per scene.

Ours: the project's equal-time comparison (`nirc-bench report`, jobs/pareto/report.py;
docs/pareto.md, "The Fig. 7 comparison") on each scene: its equal-spp rows, NIRC biased
with N_c calibrated to the paper's PT 2 spp frame time, and at each matched method's
frame time the paper's PT with the most spp that fits and the strongest PT there. MRSE
with the report's 95 % interval, FLIP with a Student-t interval over the K seeds, and
times as ratios to PT 1 spp's frame on this CPU beside the paper's (its ms on an RTX 3080
at 1080p, papers/nirc.toml). --quick renders only the rows its verdicts read
(:data:`QUICK_RUNS`, PT at :data:`QUICK_PT_AT`'s time). :func:`equal_time_figure` is also
Fig. 8 (nirc_fig8.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jobs.reproduce.measure import frame_ms
from jobs.reproduce.papers import paper_data
from jobs.reproduce.registry import Budget, Context, FigureSpec, register
from jobs.reproduce.results import Estimate, Point, Reproduction, Verdict
from jobs.views.plots import new_figure, save_png

#: Our scenes and the paper's scene whose Fig. 7 numbers stand beside them (the catalogue
#: says why: White Room is built in; cornell-box stands for the indoor Country Kitchen
#: (and Sponza), sky for the environment-lit Bistro Exterior).
SCENES = {"white-room": "White Room", "cornell-box": "Country Kitchen",
          "sky": "Bistro Exterior"}
QUANTITIES = {"mrse": "MRSE", "flip": "FLIP", "ms_per_frame": "ms per frame",
              "time_ratio": "time / PT 1 spp's"}
#: Frames each cache trains before the rendered ones, per rendered frame.
PRETRAIN_PER_FRAME = 2
#: A NIRC biased row counts as equal time against NRC when its frame costs at most this
#: factor of NRC's (the calibration's grid of N_c is coarse: 1, 2, 4, ...).
EQUAL_TIME_TOLERANCE = 1.1

#: --quick's bounds on the report's PT calibrations (jobs/pareto/report.py): spp
#: candidates up to this many (a PT row at a matched time that would spend more is
#: flagged capped: less than equal time), and no strongest-PT candidate, as its rows
#: serve no verdict here.
QUICK_MAX_PT_SPP = 32
QUICK_STRONGEST: tuple[str, ...] = ()
#: --quick's rows (the report's ``runs`` and ``pt_at``): the comparison runs the verdicts
#: read, without the grid cache (not in the paper's Fig. 7; its run and its two PT
#: calibrations were a third of a scene's time), and the paper's PT calibrated at
#: unbiased NIRC's frame time alone, the time its claim compares at.
QUICK_RUNS = ("PT 1 spp", "PT 2 spp", "NRC", "NIRC biased", "NIRC unbiased",
              "NIRC biased (equal time)")
QUICK_PT_AT = ("NIRC unbiased",)
QUICK_WHY = ("--quick: 16x16, K = 3 seeds (the least for MRSE's interval) of F = 4 frames "
             "after 8 pre-training frames (NRC's frame alone took 2 s at 16x16 on the loaded "
             "machine); per scene the 5 runs the verdicts read (no grid cache), the N_c "
             "calibration and one PT calibration, the paper's PT at unbiased NIRC's time "
             f"with spp candidates up to {QUICK_MAX_PT_SPP}, no strongest PT (unbounded, one "
             "PT calibration to NRC's frame took 7 min at load 17-20 over 18 spp candidates; "
             "the 6 PT rows took 37 % of a scene's time at load 15-19); a capped PT row has "
             "less than equal time (its note says so); timings taken on a loaded machine "
             "are used (noted)")
FULL_WHY = ("--full: 64x64, K = 4, F = 64 after 128 pre-training frames, loaded timings "
            "left out (a GPU worker or an idle machine: hours per scene on 2 cores)")
QUICK = Budget(resolution=16, seeds=3, frames=4, ref_spp=1024, grid_preset="cpu",
               why=QUICK_WHY)
FULL = Budget(resolution=64, seeds=4, frames=64, ref_spp=4096, grid_preset="cpu",
              why=FULL_WHY)

FLIP_NOTE = "FLIP: the K seeds' mean; 95 % interval: Student t (K-1 degrees of freedom)"
MRSE_NOTE = "MRSE: the report's (docs/metrics.md)"


def comparison_report(*args: Any, **kwargs: Any) -> Any:
    """The equal-time comparison (jobs/pareto/report.py), imported when first rendered."""
    from jobs.pareto.report import comparison_report as report

    return report(*args, **kwargs)


def paper_series(row: Any) -> str | None:
    """The paper's series a report row measures (None: a row the paper does not have)."""
    if row.method == "pt" and row.label in ("paper's PT 1 spp", "paper's PT 2 spp"):
        return f"pt {row.spp}spp"
    if row.method == "nrc":
        return "nrc biased"
    if row.method == "nirc":
        return f"nirc {row.params.get('estimator')}"
    return None


def _paper(scene: str, series: str | None) -> dict[str, float]:
    values, _claims = paper_data("nirc").of("fig7")
    found = {(v.series, v.quantity): v.value for v in values if v.scene == scene}
    if series is None or (series, "mrse") not in found:
        return {}
    out = {"mrse": found[(series, "mrse")], "flip": found[(series, "flip")],
           "ms_per_frame": found[(series, "compute_time")]}
    out["time_ratio"] = out["ms_per_frame"] / found[("pt 1spp", "compute_time")]
    return out


def flip(run: Any, mean: float | None) -> Estimate:
    """FLIP (the seeds' mean, as the run lists it) with its interval over the seeds."""
    from metrics.bias_intervals import bias_interval

    per_seed = [s.metrics["flip_hdr"] for s in run.seed_results if "flip_hdr" in s.metrics]
    interval, note = bias_interval(per_seed, FLIP_NOTE)
    return Estimate(value=mean, ci95=interval if mean is not None else None, note=note)


def report_rows(report: Any) -> list[tuple[str, Any]]:
    """(label, row) of the report: its equal-spp rows, then its equal-time rows that are
    other runs (NIRC biased at the budget's time says so; PT rows name their time)."""
    rows = [(row.label, row) for row in report.equal_spp]
    seen = {row.id for row in report.equal_spp}
    budget = next((row.label.removesuffix(" (budget)") for row in report.equal_time
                   if row.label.endswith(" (budget)")), "the budget")
    for row in report.equal_time:
        if row.id not in seen:
            seen.add(row.id)
            label = row.label if "(=" in row.label else f"{row.label} (= {budget} time)"
            rows.append((label, row))
    return rows


#: The mark of a row whose PT calibration reached the spp cap (less than equal time).
CAPPED = "[capped]"


#: A figure's --quick rows: (the comparison runs rendered, the matched runs with PT rows).
QuickRows = tuple[tuple[str, ...], tuple[str, ...]]


def pt_bounds(rows: QuickRows = (QUICK_RUNS, QUICK_PT_AT)) -> dict[str, Any]:
    """The report's --quick PT calibration bounds and ``rows`` (--full has none: every
    run, PT rows at every matched time, unbounded)."""
    runs, pt_at = rows
    return {"max_pt_spp": QUICK_MAX_PT_SPP, "strongest": QUICK_STRONGEST, "runs": runs,
            "pt_at": pt_at}


def pt_bounds_text(bounds: dict[str, Any]) -> str:
    """:func:`pt_bounds` as the figure's settings state them."""
    if not bounds:
        return "unbounded, at every matched run's time"
    if not bounds["pt_at"]:
        return "none (no equal-time PT rows)"
    strongest = ", ".join(bounds["strongest"]) or "none"
    return (f"at {', '.join(bounds['pt_at'])}'s time, spp candidates up to "
            f"{bounds['max_pt_spp']}, strongest PT's candidates: {strongest}")


def scene_points(ctx: Context, scene: str, paper_scene: str | None, notes: list[str],
                 bounds: dict[str, Any]) -> list[Point]:
    """The report of ``scene`` at the context's budget and ``bounds`` (:func:`pt_bounds`,
    given at --quick, whose loaded timings are used) as points (x: the row's place)."""
    b = ctx.budget
    report = comparison_report(
        scene, ctx.store, ctx.settings, resolution=b.resolution, frames=b.frames,
        seeds=b.seeds, pretrain_frames=PRETRAIN_PER_FRAME * b.frames, ref_spp=b.ref_spp,
        progress=ctx.progress, allow_loaded=bool(bounds), **bounds)
    rows = [(f"{label} {CAPPED}" if "calibration capped" in row.note else label, row)
            for label, row in report_rows(report)]
    pt1 = next((row.seconds_per_frame for _label, row in rows
                if paper_series(row) == "pt 1spp"), None)
    points = []
    for index, (label, row) in enumerate(rows):
        seconds = row.seconds_per_frame
        ratio = None if seconds is None or not pt1 else seconds / pt1
        points.append(Point(
            scene=scene, series=label, x=float(index), run_id=row.id, values={
                "mrse": Estimate(value=row.mrse, ci95=row.mrse_ci95, note=MRSE_NOTE),
                "flip": flip(ctx.store.get_run(row.id), row.flip),
                "ms_per_frame": frame_ms(row),
                "time_ratio": Estimate(value=ratio)},
            paper={} if paper_scene is None else _paper(paper_scene, paper_series(row))))
        if row.timing_flags:
            notes.append(f"{scene}, {label}: timed on a loaded machine "
                         f"({'; '.join(row.timing_flags)})")
    notes += [f"{scene}: left out {s.label}: {s.reason}" for s in report.left_out]
    notes += [f"{scene}: {s.label or s.method} not run: {s.reason}" for s in report.skipped]
    return points


# ---- Verdicts ----

def _find(points: list[Point], scene: str, test: Any) -> Point | None:
    return next((p for p in points if p.scene == scene and test(p)), None)


def interval_order(a: Estimate, b: Estimate) -> int:
    """+1 when ``a``'s 95 % interval lies below ``b``'s, -1 above, 0 overlapping/none."""
    if a.ci95 is None or b.ci95 is None:
        return 0
    return 1 if a.ci95[1] < b.ci95[0] else -1 if a.ci95[0] > b.ci95[1] else 0


def lower_error(ours: Point, theirs: Point) -> tuple[int, str]:
    """+1 when ours has the lower MRSE and FLIP, both intervals apart; -1 when either
    is higher, intervals apart; 0 otherwise; and the factors as text."""
    signs = [interval_order(ours.values[k], theirs.values[k]) for k in ("mrse", "flip")]
    mrse_o, mrse_t = ours.values["mrse"].value, theirs.values["mrse"].value
    flip_o, flip_t = ours.values["flip"].value, theirs.values["flip"].value
    if not (mrse_o and mrse_t and flip_o and flip_t):
        return 0, "MRSE or FLIP withheld"
    text = (f"MRSE {mrse_t:.3g} / {mrse_o:.3g} = {mrse_t / mrse_o:.2f}x lower, FLIP "
            f"{100 * (1 - flip_o / flip_t):.0f} % lower")
    return (-1 if -1 in signs else 1 if signs == [1, 1] else 0), text


def judge(claim: str, found: dict[str, tuple[int, str] | str], paper: str) -> Verdict:
    """Holds when ours wins with intervals apart on every scene, does not hold when it
    loses (intervals apart) on one; otherwise, or when a scene lacks the rows, not
    comparable. ``found``: per scene (sign, factors) or why there is nothing to compare."""
    detail = "; ".join(f"{scene}: {v if isinstance(v, str) else v[1]}"
                       for scene, v in found.items())
    signs = [v[0] for v in found.values() if not isinstance(v, str)]
    if not signs:
        return Verdict(claim=claim, verdict="not comparable", reason=detail or "no scene")
    if -1 in signs:
        verdict = "does not hold"
    elif len(signs) == len(found) and all(s == 1 for s in signs):
        verdict = "holds"
    else:
        verdict = "not comparable"
    why = {"holds": "lower MRSE and FLIP, intervals apart, on every scene",
           "does not hold": "higher MRSE or FLIP, intervals apart, on a scene",
           "not comparable": "intervals overlap or rows are missing on a scene"}[verdict]
    return Verdict(claim=claim, verdict=verdict, reason=f"{why}; {detail}; the paper: {paper}")


def against(points: list[Point], scenes: list[str], ours: Any, theirs: Any
            ) -> dict[str, tuple[int, str] | str]:
    """Per scene ours against theirs (:func:`lower_error`); a win against a PT row whose
    calibration was capped (less than equal time) decides nothing."""
    found: dict[str, tuple[int, str] | str] = {}
    for scene in scenes:
        a, b = _find(points, scene, ours), _find(points, scene, theirs)
        if a is None or b is None:
            found[scene] = "rows missing"
            continue
        sign, text = lower_error(a, b)
        if sign == 1 and b.series.endswith(CAPPED):
            sign, text = 0, f"{text}, but PT's spp was capped below equal time"
        found[scene] = (sign, text)
    return found


def biased_against_nrc(points: list[Point], scenes: list[str]
                       ) -> dict[str, tuple[int, str] | str]:
    """Per scene biased NIRC against NRC at equal time: the NIRC biased row of most time
    within :data:`EQUAL_TIME_TOLERANCE` of NRC's frame (none: not comparable)."""
    found: dict[str, tuple[int, str] | str] = {}
    for scene in scenes:
        nrc = _find(points, scene, lambda p: p.series == "NRC biased")
        nrc_ms = None if nrc is None else nrc.values["ms_per_frame"].value
        biased = [p for p in points if p.scene == scene and p.series.startswith("NIRC biased")
                  and p.values["ms_per_frame"].value is not None]
        if nrc is None or nrc_ms is None or not biased:
            found[scene] = "rows missing"
            continue
        fits = [p for p in biased
                if p.values["ms_per_frame"].value <= EQUAL_TIME_TOLERANCE * nrc_ms]
        if not fits:
            fastest = min(p.values["ms_per_frame"].value for p in biased)
            found[scene] = (f"no NIRC biased row within {EQUAL_TIME_TOLERANCE}x NRC's time "
                            f"(fastest {fastest / nrc_ms:.2f}x)")
            continue
        best = max(fits, key=lambda p: p.values["ms_per_frame"].value)
        sign, text = lower_error(best, nrc)
        found[scene] = (sign, f"{best.series} at {best.values['ms_per_frame'].value / nrc_ms:.2f}"
                              f"x NRC's time: {text}")
    return found


def fig7_verdicts(points: list[Point], scenes: list[str]) -> list[Verdict]:
    def unbiased(p: Point) -> bool:
        return p.series.startswith("NIRC unbiased")

    def pt_at_unbiased(p: Point) -> bool:
        return p.series.startswith("paper's PT") and "(= NIRC unbiased time)" in p.series

    def biased_at_budget(p: Point) -> bool:
        return p.series.startswith("NIRC biased") and "(= paper's PT 2 spp time)" in p.series

    def pt2(p: Point) -> bool:
        return p.series == "paper's PT 2 spp"

    return [
        judge("unbiased NIRC below PT at equal time (MRSE 3-5x, FLIP 10-38 %)",
              against(points, scenes, unbiased, pt_at_unbiased),
              "MRSE 3-5x lower, FLIP 10-38 % lower than PT 2 spp"),
        judge("biased NIRC below PT at equal time (MRSE 3.17-20.40x, FLIP 35-54 %)",
              against(points, scenes, biased_at_budget, pt2),
              "MRSE 3.17-20.40x lower, FLIP 35-54 % lower than PT 2 spp"),
        judge("biased NIRC below NRC at equal time (MRSE 1.66-2.92x, FLIP up to 34 %)",
              biased_against_nrc(points, scenes), "MRSE 1.66-2.92x lower, FLIP up to 34 %"),
    ]


def equal_time_figure(ctx: Context, scenes: dict[str, str | None], figure: str,
                      title: str, verdicts: Any, notes: list[str], quick: Budget = QUICK,
                      rows: QuickRows = (QUICK_RUNS, QUICK_PT_AT)) -> Reproduction:
    """The comparison on ``scenes`` (ours -> the paper's scene of Fig. 7's numbers, or
    None) as figure ``figure`` of the NIRC paper, with ``verdicts(points, scenes)``;
    at the figure's ``quick`` budget with the runs and PT rows ``rows``
    (:func:`pt_bounds`)."""
    b = ctx.budget
    notes = list(notes)
    bounds = pt_bounds(rows) if b == quick else {}
    points = [p for scene, theirs in scenes.items()
              for p in scene_points(ctx, scene, theirs, notes, bounds)]
    return Reproduction(
        paper="nirc", figure=figure, title=title, mode="",
        settings={"resolution": f"{b.resolution}x{b.resolution}", "seeds K": b.seeds,
                  "frames F": b.frames, "pre-training frames": PRETRAIN_PER_FRAME * b.frames,
                  "reference spp": b.ref_spp,
                  "runs": ", ".join(bounds.get("runs", ("every comparison run",))),
                  "PT calibrations": pt_bounds_text(bounds), "why": b.why},
        x_label="row", quantities=QUANTITIES, points=points,
        verdicts=verdicts(points, list(scenes)), notes=[
            "our scenes are the project's built-ins, not the paper's",
            "times: our frame on this shared 2-core CPU over PT 1 spp's, beside the paper's "
            "(RTX 3080, 1080p) over its PT 1 spp: only ratios compare",
            "MRSE: ours relative (docs/metrics.md); the paper's is printed without its "
            "scale, so compare factors between rows, not values", *notes])


def draw(reproduction: Reproduction, path: Path) -> Path:
    """Per scene, MRSE and FLIP of every row as horizontal bars with 95 % intervals."""
    scenes = list(dict.fromkeys(p.scene for p in reproduction.points))
    figure, axes = new_figure(max(len(scenes), 1), 2, reproduction.title,
                              figsize=(12, 4.2 * max(len(scenes), 1)))
    for index, scene in enumerate(scenes):
        points = [p for p in reproduction.points if p.scene == scene]
        for ax, key in zip(axes[2 * index:2 * index + 2], ("mrse", "flip"), strict=True):
            values = [p.values[key] for p in points]
            ys = range(len(points))
            widths = [v.value or 0.0 for v in values]
            errors = [[max(0.0, (v.value or 0) - v.ci95[0]) if v.ci95 else 0 for v in values],
                      [max(0.0, v.ci95[1] - (v.value or 0)) if v.ci95 else 0 for v in values]]
            ax.barh(list(ys), widths, xerr=errors, color="tab:blue", alpha=0.7)
            # The rows' labels once, left of the MRSE panel; the FLIP panel shares them.
            ax.set_yticks(list(ys), [p.series if key == "mrse" else "" for p in points],
                          fontsize="x-small")
            ax.invert_yaxis()
            ax.set_title(f"{scene}: {reproduction.quantities[key]}", fontsize="medium")
    return save_png(figure, path)


def measure(ctx: Context) -> Reproduction:
    return equal_time_figure(
        ctx, dict(SCENES), "fig7", "[DKHD24] Fig. 7: equal-time comparison of PT, NRC and "
        "NIRC", fig7_verdicts, ["the paper's numbers beside ours: " + ", ".join(
            f"{ours} <- {theirs}" for ours, theirs in SCENES.items())])


FIGURE = register(FigureSpec("nirc", "fig7", "Equal-time comparison: PT 1 and 2 spp, NRC "
                             "biased, NIRC biased and unbiased, the strongest PT (FLIP, MRSE, "
                             "time as ratios to PT 1 spp)", {"quick": QUICK, "full": FULL},
                             measure, draw))
