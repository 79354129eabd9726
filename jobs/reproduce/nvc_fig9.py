"""[BM25] Fig. 9: screen-space ReSTIR against neural light sampling at equal time,
ReSTIR's spp calibrated to neural light sampling's frame time (docs/protocol.md,
"Equal time"); HDR-FLIP as a ratio to ReSTIR's (jobs/reproduce/nvc_compare.py; Fig. 1
is the same at one sample per pixel)."""

from __future__ import annotations

from jobs.reproduce.nvc_compare import FULL, QUICK, draw, measure_comparison
from jobs.reproduce.registry import Context, FigureSpec, register
from jobs.reproduce.results import Reproduction


def measure(ctx: Context) -> Reproduction:
    return measure_comparison(ctx, "fig9", equal_time=True)


FIGURE = register(FigureSpec("nvc", "fig9", "restir-di at nvc-lights' frame time on "
                             "many-lights (for Sponza): FLIP over ReSTIR's",
                             {"quick": QUICK, "full": FULL}, measure, draw))
