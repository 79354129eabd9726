"""[BM25] Fig. 1: screen-space ReSTIR, neural light sampling and Neural DI at one
sample per pixel after training: HDR-FLIP and frame time as ratios to ReSTIR's
(jobs/reproduce/nvc_compare.py; Fig. 9 is the same at equal time)."""

from __future__ import annotations

from jobs.reproduce.nvc_compare import FULL, QUICK, draw, measure_comparison
from jobs.reproduce.registry import Context, FigureSpec, register
from jobs.reproduce.results import Reproduction


def measure(ctx: Context) -> Reproduction:
    return measure_comparison(ctx, "fig1", equal_time=False)


FIGURE = register(FigureSpec("nvc", "fig1", "restir-di, nvc-lights and neural-di at 1 spp on "
                             "many-lights (for Kitchen): FLIP and frame time over ReSTIR's",
                             {"quick": QUICK, "full": FULL}, measure, draw))
