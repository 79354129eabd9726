"""``nirc-bench reproduce``: list the papers' figures this project reproduces, and
reproduce one (jobs/reproduce; docs/reproduce.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from service.cli_common import DataDir, JsonOut, console, open_settings, open_store, print_json
from service.errors import UsageError

reproduce_app = typer.Typer(
    help="Reproduce papers' figures and tables: our numbers with 95 % intervals beside "
         "the paper's (see 'reproduce list').", no_args_is_help=True, rich_markup_mode=None)


@reproduce_app.command("list")
def list_figures(as_json: JsonOut = False) -> None:
    """Every figure and table of the three papers: the scenes standing in for the
    paper's, whether a command runs it (with its --quick budget) or what it needs, and
    the claims it checks with today's verdict."""
    from jobs.reproduce.catalogue import listing
    from jobs.reproduce.registry import figures

    quick = {(f.paper, f.key): f.budgets["quick"] for f in figures()}
    rows = listing()
    for row in rows:
        budget = quick.get((row["paper"], row["figure"]))
        row["quick"] = budget and {"resolution": budget.resolution, "seeds": budget.seeds,
                                   "grid_preset": budget.grid_preset}
    if as_json:
        print_json(rows)
        return
    for row in rows:
        if row["command"]:
            q = row["quick"]
            status = (f"runs: {row['command']} (--quick: {q['resolution']}x"
                      f"{q['resolution']}, K {q['seeds']}, grid {q['grid_preset']})")
        else:
            status = f"not yet: needs {row['needs']}"
        lines = [f"[{row['reference']}] {row['figure']}: {row['title']}",
                 f"  scenes: {', '.join(row['scenes']) or 'none'} ({row['stand_in']})",
                 f"  status: {status}"]
        lines += [f"  claim ({c['where']}): \"{c['quote']}\" -> {c['verdict']}"
                  for c in row["claims"]]
        console.print("\n".join(lines) + "\n", markup=False, highlight=False)


def _paper_command(paper: str) -> None:
    """Register ``reproduce <paper> FIGURE`` for one paper of the registry."""
    from jobs.reproduce.registry import PAPERS

    def command(
        figure: Annotated[str, typer.Argument(help="the figure's key (see 'reproduce list')")],
        quick: Annotated[bool, typer.Option(
            "--quick/--full", help="--quick: minutes on 2 cores (small images, K = 4); "
                                   "--full: the figure's full budget")] = True,
        out: Annotated[Path | None, typer.Option(
            "--out", help="folder for figure.png, table.md and table.json (default: "
                          "<data>/reproduce/<paper>-<figure>)")] = None,
        data_dir: DataDir = None,
        as_json: JsonOut = False,
    ) -> None:
        from jobs.reproduce.catalogue import catalogue_entry
        from jobs.reproduce.registry import ReproduceError, get_figure
        from jobs.reproduce.run import default_out_dir, reproduce
        from service.progress import progress_reporter

        try:
            get_figure(paper, figure)   # a bad name fails before anything renders
        except ReproduceError as err:
            entry = catalogue_entry(paper, figure)
            if entry is not None:
                raise UsageError(f"{paper} {figure} is not reproduced yet: it needs "
                                 f"{entry.needs}") from None
            raise UsageError(str(err)) from None
        settings = open_settings(data_dir)
        store = open_store(settings)
        folder = out or default_out_dir(settings, paper, figure)
        with progress_reporter(console, quiet=as_json) as report:
            result, paths = reproduce(paper, figure, "quick" if quick else "full", folder,
                                      store, settings, progress=report)
        if as_json:
            print_json({"files": {k: str(v) for k, v in paths.items()},
                        "result": result.model_dump(mode="json")})
            return
        console.print(result.markdown(), markup=False, highlight=False)
        for kind, path in paths.items():
            console.print(f"{kind}: {path}", markup=False, highlight=False)

    command.__doc__ = (f"Reproduce a figure or table of {PAPERS[paper].title} "
                       f"[{PAPERS[paper].reference}].")
    reproduce_app.command(paper)(command)


def _register_papers() -> None:
    from jobs.reproduce.registry import PAPERS

    for paper in PAPERS:
        _paper_command(paper)


_register_papers()
