"""``nirc-bench reproduce``: list the papers' figures this project reproduces, reproduce
one (here, or as a job of a service with ``--server``), or every registered one in turn
(``--all``) (jobs/reproduce; docs/reproduce.md)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from service.cli_common import (
    ApiKeyOpt,
    DataDir,
    JsonOut,
    Server,
    console,
    open_settings,
    open_store,
    print_json,
    submit_and_wait,
)
from service.errors import UsageError

if TYPE_CHECKING:
    from jobs.reproduce.results import FigureTime, Provenance

reproduce_app = typer.Typer(
    help="Reproduce papers' figures and tables: our numbers with 95 % intervals beside "
         "the paper's (see 'reproduce list').", no_args_is_help=True, rich_markup_mode=None)

#: ``make reproduce``'s goal: every figure at --quick within an hour on 2 cores (``--all``
#: says when its total is over it; its exit status reports failures only).
GOAL_S = 3600.0

Quick = Annotated[bool, typer.Option(
    "--quick/--full", help="--quick: minutes on 2 cores (small images, K = 4); "
                           "--full: the figure's full budget")]


@reproduce_app.callback(invoke_without_command=True)
def reproduce_all(
    ctx: typer.Context,
    every: Annotated[bool, typer.Option(
        "--all", help="reproduce every registered figure in turn (each into its default "
                      "folder), going on past a failing one; one summary of verdicts and "
                      "of wall and CPU times at the end; exit 1 if any failed")] = False,
    quick: Quick = True,
    data_dir: DataDir = None,
) -> None:
    """Reproduce papers' figures and tables."""
    if ctx.invoked_subcommand is not None:
        if every:
            raise UsageError("--all reproduces every figure: give no command with it")
        # Given here, they would be dropped: the command has its own (its data folder
        # would be the default one, its mode --quick).
        given = [flag for name, flag in (("quick", "--quick/--full"), ("data_dir", "--data-dir"))
                 if getattr(ctx.get_parameter_source(name), "name", "") == "COMMANDLINE"]
        if given:
            raise UsageError(f"{' and '.join(given)} before the command apply to --all alone: "
                             "give them after the figure, e.g. 'reproduce nirc fig7 --full "
                             "--data-dir D'")
        return
    if not every:
        raise UsageError("give a command ('reproduce list', 'reproduce <paper> <figure>') "
                         "or --all")
    from jobs.reproduce.registry import figures
    from jobs.reproduce.run import Clock, default_out_dir, latest_times, reproduce
    from service.progress import progress_reporter

    settings = open_settings(data_dir)
    store = open_store(settings)
    mode = "quick" if quick else "full"
    last = latest_times(settings)
    summary: list[str] = []
    times: list[tuple[str, FigureTime]] = []
    failed = 0
    for spec in figures():
        name = f"{spec.paper} {spec.key}"
        before = last.get((spec.paper, spec.key))
        console.print(f"reproducing {name} ({mode}"
                      f"{f'; last here: {_last_time(before)}' if before else ''})",
                      markup=False, highlight=False)
        clock = Clock()
        try:
            with progress_reporter(console) as report:
                result, _paths = reproduce(spec.paper, spec.key, mode,
                                           default_out_dir(settings, spec.paper, spec.key),
                                           store, settings, progress=report)
            verdicts = "; ".join(f"{v.claim}: {v.verdict}" for v in result.verdicts)
            summary.append(f"{name}: {verdicts or 'no verdicts'}")
        except Exception as err:  # noqa: BLE001 - one figure's failure ends only it
            failed += 1
            summary.append(f"{name}: FAILED ({type(err).__name__}: {' '.join(str(err).split())})")
            name += " (failed)"
        took = clock.read()
        times.append((name, took))
        console.print(f"{name}: took {took.text()}", markup=False, highlight=False)
    console.print("\n".join(["", f"{len(summary) - failed} of {len(summary)} figures "
                              "reproduced:", *summary, "", *time_summary(times)]),
                  markup=False, highlight=False)
    if failed:
        raise typer.Exit(1)


def time_summary(times: list[tuple[str, FigureTime]]) -> list[str]:
    """A line per figure with its wall and CPU seconds, then the total, and whether it is
    over ``make reproduce``'s goal (:data:`GOAL_S`; a statement, not a failure)."""
    wall_s = sum(time.wall_s for _, time in times)
    cpu_s = sum(time.cpu_s for _, time in times)
    lines = [f"{name}: {time.text()}" for name, time in times]
    lines.append(f"total: wall {wall_s:.0f} s ({wall_s / 60:.1f} min), CPU {cpu_s:.0f} s")
    if wall_s > GOAL_S:
        lines.append(f"over the {GOAL_S / 60:.0f}-minute goal by {(wall_s - GOAL_S) / 60:.1f} "
                     "min")
    return lines


def _last_time(provenance: Provenance) -> str:
    """What a stored reproduction took (one :func:`latest_times` found: it has a time)."""
    return (f"{provenance.time.text()}, {provenance.mode}, "
            f"{provenance.finished_at:%Y-%m-%d %H:%M} UTC")


@reproduce_app.command("list")
def list_figures(as_json: JsonOut = False, data_dir: DataDir = None) -> None:
    """Every figure and table of the three papers: the scenes standing in for the
    paper's, whether a command runs it (with its --quick budget) or what it needs, the
    claims it checks with today's verdict, and what its latest reproduction stored in
    the data folder took."""
    from jobs.reproduce.catalogue import listing
    from jobs.reproduce.registry import figures
    from jobs.reproduce.run import latest_times

    quick = {(f.paper, f.key): f.budgets["quick"] for f in figures()}
    last = latest_times(open_settings(data_dir))
    rows = listing()
    for row in rows:
        budget = quick.get((row["paper"], row["figure"]))
        row["quick"] = budget and {"resolution": budget.resolution, "seeds": budget.seeds,
                                   "grid_preset": budget.grid_preset}
        before = last.get((row["paper"], row["figure"]))
        row["last_time"] = before and {"mode": before.mode,
                                       "finished_at": before.finished_at.isoformat(),
                                       **before.time.model_dump()}
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
        before = last.get((row["paper"], row["figure"]))
        lines += [f"  last here: {_last_time(before)}"] if before else []
        lines += [f"  claim ({c['where']}): \"{c['quote']}\" -> {c['verdict']}"
                  for c in row["claims"]]
        console.print("\n".join(lines) + "\n", markup=False, highlight=False)


def _paper_command(paper: str) -> None:
    """Register ``reproduce <paper> FIGURE`` for one paper of the registry."""
    from jobs.reproduce.registry import PAPERS

    def command(
        figure: Annotated[str, typer.Argument(help="the figure's key (see 'reproduce list')")],
        quick: Quick = True,
        out: Annotated[Path | None, typer.Option(
            "--out", help="folder for figure.png, table.md and table.json (default: "
                          "<data>/reproduce/<paper>-<figure>)")] = None,
        data_dir: DataDir = None,
        as_json: JsonOut = False,
        server: Server = None,
        api_key: ApiKeyOpt = None,
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
        mode = "quick" if quick else "full"
        if server:
            if out is not None:
                raise UsageError("--out writes local files: it cannot be used with --server "
                                 "(the service writes the reproduction in its data folder)")
            _run_remote(server, api_key, {"paper": paper, "figure": figure, "mode": mode},
                        as_json)
            return
        settings = open_settings(data_dir)
        store = open_store(settings)
        folder = out or default_out_dir(settings, paper, figure)
        with progress_reporter(console, quiet=as_json) as report:
            result, paths = reproduce(paper, figure, mode, folder,
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


def _run_remote(server: str, api_key: str | None, spec: dict[str, str],
                as_json: bool) -> None:
    """Submit the reproduction to the service at ``server`` as a job, follow its
    progress, print the stored reproduction (its table, verdicts and provenance)."""
    from jobs.reproduce.results import Reproduction
    from service.client import ServiceClient

    client = ServiceClient(server, api_key)
    job = submit_and_wait(client, "reproduce", spec, server, as_json)
    stored = client.get(f"/api/v1/reproductions/{job['id']}")
    if as_json:
        print_json(stored)
        return
    console.print(Reproduction.model_validate(stored["reproduction"]).markdown(),
                  markup=False, highlight=False)
    console.print(f"stored on the service as {stored['figure_png']} (job {job['id']}, "
                  f"commit {stored['provenance']['git_commit']}); its PNG: "
                  f"{server.rstrip('/')}{stored['figure_url']}",
                  markup=False, highlight=False)


def _register_papers() -> None:
    from jobs.reproduce.registry import PAPERS

    for paper in PAPERS:
        _paper_command(paper)


_register_papers()
