"""[DKHD24] Fig. 8 (Sec. 6.2): biased NIRC against NRC and PT with the sky light off
(the paper's Bistro): MRSE and FLIP.

Ours: Fig. 7's equal-time comparison (:func:`jobs.reproduce.nirc_fig7.equal_time_figure`)
on `door`, lit without an environment; the paper prints no numbers for it, so the table
holds ours alone and the verdict is Fig. 7's biased NIRC against NRC at equal time."""

from __future__ import annotations

from dataclasses import replace

from jobs.reproduce import nirc_fig7
from jobs.reproduce.nirc_fig7 import (
    FULL,
    biased_against_nrc,
    draw,
    equal_time_figure,
    judge,
)
from jobs.reproduce.registry import Context, FigureSpec, register
from jobs.reproduce.results import Point, Reproduction, Verdict

SCENE = "door"
#: --quick renders the runs its verdict reads (NRC, biased NIRC at N_c 4 and at PT 2 spp's
#: time) and PT at 1 and 2 spp (the time ratios' unit and the N_c budget), no equal-time
#: PT rows: they judge nothing here, nor do unbiased NIRC and the grid cache.
QUICK_RUNS = ("PT 1 spp", "PT 2 spp", "NRC", "NIRC biased", "NIRC biased (equal time)")
QUICK_WHY = ("--quick: 16x16, K = 3 seeds of F = 4 frames after 8 pre-training frames; "
             "the 5 runs the verdict reads, no equal-time PT rows (--full: every run, PT "
             "at every matched time); timings taken on a loaded machine are used (noted)")
QUICK = replace(nirc_fig7.QUICK, why=QUICK_WHY)


def fig8_verdicts(points: list[Point], scenes: list[str]) -> list[Verdict]:
    return [judge("biased NIRC below NRC at equal time without the sky light",
                  biased_against_nrc(points, scenes), "lower error than NRC (no numbers)")]


def measure(ctx: Context) -> Reproduction:
    return equal_time_figure(ctx, {SCENE: None}, "fig8", "[DKHD24] Fig. 8: NIRC, NRC and "
                             "PT without environment light (door)", fig8_verdicts,
                             ["door stands for the paper's Bistro with its sky light off: it "
                              "has no environment light"], quick=QUICK, rows=(QUICK_RUNS, ()))


FIGURE = register(FigureSpec("nirc", "fig8", "NIRC against NRC and PT without environment "
                             "light (door): MRSE, FLIP and time as ratios to PT 1 spp",
                             {"quick": QUICK, "full": FULL}, measure, draw))
