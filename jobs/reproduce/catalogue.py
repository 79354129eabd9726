"""Every figure and table of the three papers, with the built-in scenes standing in for
the papers' and, while no command reproduces it, what one needs: the data behind
``nirc-bench reproduce list`` and the claims section of docs/reproduce.md.

A figure's status is read from the registry (jobs/reproduce/registry.py): ``runs`` once
a module registers it, ``not yet`` with the entry's ``needs`` before that. The claims are
those of the paper's data file (papers/<paper>.toml), with today's verdict where one of
our measurements has judged them.

``python -m jobs.reproduce.catalogue`` prints the claims section of docs/reproduce.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from jobs.reproduce.papers import paper_data
from jobs.reproduce.registry import PAPERS, figures


@dataclass(frozen=True)
class CatalogueEntry:
    paper: str                 # a key of registry.PAPERS
    figure: str                # the key its command uses: 'fig7', 'table1'
    title: str
    scenes: tuple[str, ...]    # built-in scenes standing in for the paper's
    stand_in: str              # the paper's scenes, and why ours stand for them
    needs: str                 # what a command for it needs, while none is registered


_NONE = "no scene: a discrete sampling tree whose moments are computed in closed form"
_KITCHEN = ("the paper's Kitchen and Sponza (32 lights) are not built in; many-lights "
            "holds 32 lights behind occluders, the case the visibility cache is for")

CATALOGUE: tuple[CatalogueEntry, ...] = (
    CatalogueEntry("vt", "fig4", "Discrete test case of variance bounding: MSE against the "
                   "variance threshold on a sampling tree", (), _NONE,
                   "a discrete-tree module (local variances of each node in closed form) "
                   "running var-bound's termination rule on it"),
    CatalogueEntry("vt", "fig5", "Discrete test case of MSE minimization: MSE against sample "
                   "count per sample target, biased inner caches", (), _NONE,
                   "the discrete-tree module with biased inner caches, mse-min's rule and "
                   "an exhaustive search for the optimal termination"),
    CatalogueEntry("vt", "fig7", "Variance bounding on door at roulette survival 100, 60, "
                   "20 %: rVar, rBias², MSE and path length against t", ("door",),
                   "door is the paper's Veach Door, built in", ""),
    CatalogueEntry("vt", "fig9", "MSE minimization: MSE against sample count per sample "
                   "target, PT and area-spread", ("cornell-box", "white-room"),
                   "the paper's Bunny (a bunny in a Cornell box) and Classroom are not built "
                   "in: cornell-box stands for Bunny, white-room (indirectly lit) for "
                   "Classroom", ""),
    CatalogueEntry("vt", "fig10", "Equal-sample comparison of PT, var-bound t = 1, mse-min "
                   "s = 100 and area-spread c = 0.01, at 1 spp and denoised after four "
                   "frames", ("cornell-box", "door", "corridor"),
                   "the paper's scenes include door and corridor, built in; cornell-box "
                   "stands for its Bunny",
                   "a figure module on the four policies' 1-spp and denoised error at equal "
                   "samples (OIDN standing in for the paper's SVGF)"),
    CatalogueEntry("vt", "fig11", "Var-bound t = 10 against area-spread on door: denoised "
                   "output, FLIP and path length per pixel", ("door",),
                   "door is the paper's Veach Door, built in",
                   "a figure module with FLIP and per-pixel path length maps of the two "
                   "policies after the denoiser"),
    CatalogueEntry("vt", "table1", "Path length and kernel times per policy on door and "
                   "corridor", ("door", "corridor"),
                   "door and corridor are the paper's Door and Corridor, built in", ""),
    CatalogueEntry("nvc", "fig1", "ReSTIR, neural light sampling and Neural DI on Kitchen "
                   "(32 lights): FLIP and time per frame", ("many-lights",), _KITCHEN,
                   "a figure module comparing restir-di, nvc-lights and neural-di at 1 spp "
                   "after training, FLIP and time as ratios to restir-di"),
    CatalogueEntry("nvc", "fig5", "Biased visibility against visibility clamped to 0.001: "
                   "1 spp and converged", ("many-lights",), _KITCHEN,
                   "nvc-lights' clamp as a swept parameter (off, 0.001) and the bias of the "
                   "converged image against the reference"),
    CatalogueEntry("nvc", "fig6", "NRC, neural light sampling and ReSTIR over 128 frames: "
                   "FLIP per frame", ("many-lights",), _KITCHEN,
                   "FLIP per frame over 128 frames for nrc-di, nvc-lights and restir-di"),
    CatalogueEntry("nvc", "fig7", "ReSTIR with clustered-NVC initial candidates after a "
                   "disocclusion in every pixel (Subway, 60k lights)", ("many-lights-300",),
                   "the paper's Subway (60k lights) is not built in; many-lights-300 has the "
                   "most lights of the built-ins", ""),
    CatalogueEntry("nvc", "fig9", "Neural light sampling against ReSTIR on Sponza (32 "
                   "lights) at equal time", ("many-lights",), _KITCHEN,
                   "the fig1 module at equal time instead of equal samples"),
    CatalogueEntry("nirc", "fig4", "FLIP per training epoch of the biased and unbiased "
                   "estimators trained with L_V, L2 and relative L2", ("cornell-box", "door"),
                   "the paper's scenes are not named; cornell-box and door are a direct- and "
                   "an indirect-lit case", ""),
    CatalogueEntry("nirc", "fig5", "Scalability and ablation of the inference pipeline: "
                   "time per additional neural sample (Bistro Exterior)", ("sky",),
                   "Bistro Exterior is not built in; sky is the outdoor, environment-lit one",
                   "a sweep of N_c timing nirc per neural sample; the paper's CUDA fusion "
                   "steps have no counterpart on the LLVM backend"),
    CatalogueEntry("nirc", "fig6", "Equal-memory comparison of SH, vMF, NCV, NIRC and SS "
                   "NIRC: relative variance of the residual estimator",
                   ("cornell-box", "door", "white-room", "sky"),
                   "the paper's scenes are not built in; four built-ins lit directly, "
                   "indirectly and by an environment stand for them",
                   "the control-variate records (cv-sh, cv-vmf, ncv) beside nirc and ss-nirc "
                   "and V_rel of the residual per model per training frame"),
    CatalogueEntry("nirc", "fig7", "Equal-time comparison: PT 1 and 2 spp, NRC biased, NIRC "
                   "biased and unbiased (FLIP, MRSE, time)", ("white-room", "cornell-box",
                                                            "sky"),
                   "White Room is built in; cornell-box stands for the indoor Sponza and "
                   "Country Kitchen, sky for Bistro Exterior",
                   "a figure module over the calibrated equal-time comparison of pt, nrc "
                   "and nirc (biased, unbiased); times as CPU ratios, not the paper's ms"),
    CatalogueEntry("nirc", "fig8", "NIRC against NRC and PT on Bistro with the environment "
                   "light off: MRSE and FLIP", ("door",),
                   "Bistro is not built in; door is lit without an environment, the case "
                   "the figure isolates",
                   "the fig7 module on a scene without environment light"),
    CatalogueEntry("nirc", "fig9", "Neural samples split between the first and second "
                   "vertex (N_c¹, N_c²), up to 5 vertices, no roulette",
                   ("cornell-box", "white-room"),
                   "Sponza and Country Kitchen are not built in; two indoor scenes of "
                   "different materials stand for them",
                   "a sweep over nc pairs at a fixed total with roulette off"),
    CatalogueEntry("nirc", "table1", "Time breakdown of rendering and neural kernels with "
                   "the biased estimator", ("white-room", "cornell-box", "sky"),
                   "as fig7", "a table over nirc's kernel breakdown (render, training, "
                   "encoding, inference) as shares of the frame, not the paper's ms"),
    CatalogueEntry("nirc", "fig10", "Animated Bistro Exterior: MRSE and FLIP per frame of "
                   "NIRC, NRC and PT", ("cornell-box",),
                   "the animated Bistro is not built in; cornell-box with its small box "
                   "moving every frame of the run (a state and reference per frame)", ""),
    CatalogueEntry("nirc", "fig11", "NIRC against NVC for direct illumination with MLMC, "
                   "N_c = 7 (San Miguel)", ("sky",),
                   "San Miguel is not built in; sky is lit by the environment map the "
                   "visibility cache samples",
                   "a figure module comparing nirc and nirc-nvc-env at N_c = 7, error and "
                   "V_rel per training frame"),
    CatalogueEntry("nirc", "fig12", "Termination heuristics (BTH, SPH) and per-pixel "
                   "adaptive termination: NIRC against NRC", ("white-room", "cornell-glossy",
                                                              "door"),
                   "The White Room is built in; cornell-glossy stands for Glossy Sponza, "
                   "door for the indirect-lit Bistro Exterior",
                   "the balanced and spread-angle heuristics as a swept parameter of nirc "
                   "and nrc, and the per-pixel adaptive policy (a converged reference per "
                   "pixel decides)"),
    CatalogueEntry("nirc", "fig13", "Per-pixel adaptive termination swept over epsilon: "
                   "MRSE, FLIP and % indirect bounces", ("white-room", "cornell-glossy"),
                   "as fig12", "the fig12 adaptive policy swept over epsilon and the % "
                   "indirect-bounce count per run"),
    CatalogueEntry("nirc", "fig14", "Signed squared difference of the standard deviations "
                   "of MC and MLMC for direct illumination", ("sky",),
                   "the paper's foliage is not built in; sky's environment light gives the "
                   "smooth regions where MLMC helps",
                   "per-pixel standard-deviation maps of pt and nirc unbiased (direct only)"),
    CatalogueEntry("nirc", "fig15", "Hidden layers D of the cache against the MSE of its "
                   "incident radiance, and time per neural sample",
                   ("cornell-box", "white-room"),
                   "Cornell Box and White Room are built in; New Sponza is not",
                   "nirc's hidden-layer count as a parameter and the cache's MSE against "
                   "reference incident radiance at chosen points"),
)


def catalogue_entry(paper: str, figure: str) -> CatalogueEntry | None:
    return next((e for e in CATALOGUE if (e.paper, e.figure) == (paper, figure)), None)


def listing() -> list[dict[str, Any]]:
    """Every catalogued figure, in catalogue order: paper, figure, title, scenes, status
    (``runs`` with its command, ``not yet`` with what it needs) and its claims."""
    registered = {(f.paper, f.key): f for f in figures()}
    rows = []
    for entry in CATALOGUE:
        spec = registered.get((entry.paper, entry.figure))
        _values, claims = paper_data(entry.paper).of(entry.figure)
        rows.append({
            "paper": entry.paper, "reference": PAPERS[entry.paper].reference,
            "figure": entry.figure, "title": spec.title if spec else entry.title,
            "scenes": list(entry.scenes), "stand_in": entry.stand_in,
            "status": "runs" if spec else "not yet",
            "command": f"nirc-bench reproduce {entry.paper} {entry.figure}" if spec else None,
            "needs": None if spec else entry.needs,
            "claims": [{"quote": c.quote, "where": _where(c.page, c.section),
                        "verdict": _verdict(c.verdict, spec is not None)} for c in claims]})
    return rows


def _where(page: int | None, section: str | None) -> str:
    return f"p. {page}" if page is not None else f"{section}"


def _verdict(verdict: str | None, runs: bool) -> str:
    if verdict:
        return verdict
    return "not judged yet (its command runs)" if runs else "not yet run"


def claims_markdown() -> str:
    """The claims section of docs/reproduce.md: per figure its status and each claim with
    today's verdict."""
    lines = []
    for row in listing():
        status = f"`{row['command']}`" if row["command"] else f"not yet: needs {row['needs']}"
        scenes = ", ".join(f"`{s}`" for s in row["scenes"]) or "none"
        lines += [f"### [{row['reference']}] {row['figure']}: {row['title']}", "",
                  f"Status: {status}. Scenes: {scenes} ({row['stand_in']}).", ""]
        lines += ["| claim | where | verdict |", "|---|---|---|"]
        lines += [f"| {_cell(c['quote'])} | {c['where']} | {_cell(c['verdict'])} |"
                  for c in row["claims"]]
        lines.append("")
    return "\n".join(lines).rstrip("\n")


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


if __name__ == "__main__":
    print(claims_markdown())
