"""``nirc-bench reproduce``: list the papers' figures this project reproduces, and
reproduce one (jobs/reproduce; docs/reproduce.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from service.cli_common import DataDir, JsonOut, console, open_settings, open_store, print_json
from service.errors import UsageError

reproduce_app = typer.Typer(
    help="Reproduce papers' figures and tables: our numbers with 95 % intervals beside "
         "the paper's (see 'reproduce list').", no_args_is_help=True, rich_markup_mode=None)


@reproduce_app.command("list")
def list_figures(as_json: JsonOut = False) -> None:
    """The figures each paper's command reproduces, with their --quick budget."""
    from jobs.reproduce.registry import PAPERS, figures

    rows = [{"paper": f.paper, "figure": f.key, "title": f.title,
             "quick": {"resolution": f.budgets["quick"].resolution,
                       "seeds": f.budgets["quick"].seeds,
                       "grid_preset": f.budgets["quick"].grid_preset},
             "command": f"nirc-bench reproduce {f.paper} {f.key}"} for f in figures()]
    if as_json:
        print_json(rows)
        return
    table = Table(title="reproducible figures")
    for column in ("command", "paper", "what", "--quick"):
        table.add_column(column)
    for row in rows:
        quick = row["quick"]
        table.add_row(escape(row["command"]), escape(PAPERS[row["paper"]].reference),
                      escape(row["title"]), f"{quick['resolution']}x{quick['resolution']}, "
                      f"K {quick['seeds']}, grid {quick['grid_preset']}")
    console.print(table)


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
        from jobs.reproduce.registry import ReproduceError, get_figure
        from jobs.reproduce.run import default_out_dir, reproduce
        from service.progress import progress_reporter

        try:
            get_figure(paper, figure)   # a bad name fails before anything renders
        except ReproduceError as err:
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
