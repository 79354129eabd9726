"""``nirc-bench runs``: find, inspect, compare, export and label stored runs."""

from __future__ import annotations

import csv
import json
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table

from service.cli_common import DataDir, JsonOut, console, open_settings, open_store, print_json
from service.errors import UsageError

runs_app = typer.Typer(help="Stored runs: list, show, compare, export, name and tag them.",
                       no_args_is_help=True, rich_markup_mode=None)

#: The columns ``runs list`` shows unless --columns says otherwise: they fit 120 columns
#: of terminal with the labels of sweep points (``--columns`` shows any other).
DEFAULT_COLUMNS = ("id", "created_at", "scene", "method_label", "resolution", "spp", "frames",
                   "mrse", "ms", "git_commit")
#: Columns that are numbers (or, like a commit, read as one word): never wrapped or cut.
NUMBER_COLUMNS = ("id", "spp", "frames", "seeds", "mrse", "flip", "psnr", "rbias2", "rvar",
                  "ms", "seconds_per_frame", "resolution", "git_commit")
#: Shorter headers of the table (--columns, --sort, CSV and JSON use the names).
HEADERS = {"created_at": "created", "method_label": "label", "resolution": "res",
           "git_commit": "commit"}

RunId = Annotated[int, typer.Argument(help="a run id (see `nirc-bench runs list`)", min=1)]


def parse_pairs(texts: list[str] | None, option: str, parse_json: bool = False) -> dict[str, Any]:
    """'NAME=VALUE' options as a dict (values read as JSON when ``parse_json`` and they
    parse, else kept as text)."""
    pairs: dict[str, Any] = {}
    for text in texts or []:
        name, sep, value = text.partition("=")
        if not sep or not name.strip():
            raise UsageError(f"{option}: expected NAME=VALUE, got '{text}'")
        if parse_json:
            try:
                value = json.loads(value)
            except json.JSONDecodeError:
                pass
        pairs[name.strip()] = value
    return pairs


def _date(text: str | None, option: str) -> datetime | None:
    """An ISO date or time ('2026-11-24', '2026-11-24T18:00'); UTC unless it says."""
    if text is None:
        return None
    try:
        value = datetime.fromisoformat(text)
    except ValueError:
        raise UsageError(f"{option}: '{text}' is not a date like 2026-11-24 or "
                         "2026-11-24T18:00") from None
    return value if value.tzinfo else value.replace(tzinfo=UTC)


def _get_run(store: Any, run_id: int) -> Any:
    run = store.get_run(run_id)
    if run is None:
        raise UsageError(f"no run {run_id} in this data folder (see `nirc-bench runs list`)")
    return run


def _text(value: Any) -> str:
    """A cell as plain text: floats to 3 digits, times to the minute, lists compact."""
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.3g}"
    if isinstance(value, datetime):
        return value.strftime("%Y-%m-%d %H:%M")
    if isinstance(value, list | dict):
        return json.dumps(value, separators=(",", ":"))
    return str(value)


def _cell(column: str, value: Any, below_floor: list[str]) -> str:
    """A table cell (:func:`_text`), short where the column allows: a square resolution
    as '32²', a commit as its first 7 characters (and '-dirty'), an interval's ends to 3
    digits as every number ('[0.0442, 0.0607]'; CSV and JSON keep every digit). A
    noise-corrected metric of the row's ``below_floor`` (negative: below the noise floor,
    read as ~0) reads '<0 (noise, -0.00123)', not as a small error to rank by."""
    if column in below_floor:
        return f"<0 (noise, {_text(value)})"
    if column.endswith("_ci95") and isinstance(value, list):
        return f"[{', '.join(map(_text, value))}]"
    if column == "resolution" and isinstance(value, list) and len(value) == 2:
        width, height = value
        return f"{width}²" if width == height else f"{width}×{height}"
    if column == "git_commit" and isinstance(value, str) and len(value) > 7:
        return value[:7] + ("-dirty" if value.endswith("-dirty") else "")
    return _text(value)


@runs_app.command("list")
def list_runs(
    scene: Annotated[str | None, typer.Option("--scene", "-s", help="scene name")] = None,
    method: Annotated[str | None, typer.Option("--method", "-m", help="method name")] = None,
    param: Annotated[list[str] | None, typer.Option(
        "--param", "-p", help="method parameter NAME=VALUE the run has (repeatable)")] = None,
    device: Annotated[str | None, typer.Option("--device", help="device key")] = None,
    commit: Annotated[str | None, typer.Option(
        "--commit", help="a commit (prefix) or branch the run was made by")] = None,
    since: Annotated[str | None, typer.Option("--since", help="started on or after, "
                                                              "e.g. 2026-11-24")] = None,
    until: Annotated[str | None, typer.Option("--until", help="started before")] = None,
    name: Annotated[str | None, typer.Option("--name", help="the run's name")] = None,
    tag: Annotated[list[str] | None, typer.Option(
        "--tag", help="KEY=VALUE tag the run has (repeatable)")] = None,
    sort: Annotated[str, typer.Option(
        "--sort", help="a column to sort by, '-' first for descending (e.g. mrse, -ms, "
                       "params.nc)")] = "-created_at",
    columns: Annotated[str | None, typer.Option(
        "--columns", help="comma list of columns: any field of `runs list --json`, "
                          "'changed' (resolved parameters not at their default), 'ms', "
                          "params.NAME, "
                          f"tags.NAME (default: {','.join(DEFAULT_COLUMNS)})")] = None,
    limit: Annotated[int, typer.Option("--limit", min=1, max=100_000,
                                       help="list at most this many runs")] = 50,
    as_json: JsonOut = False,
    as_csv: Annotated[bool, typer.Option("--csv", help="print CSV instead of a table")] = False,
    data_dir: DataDir = None,
) -> None:
    """Stored runs, newest first: filter, sort, choose columns."""
    from jobs.views.run_query import RunFilter, check_column, find_runs, run_value

    if as_json and as_csv:
        raise UsageError("choose one of --json and --csv")
    chosen = [check_column(c.strip()) for c in (columns.split(",") if columns
                                                else DEFAULT_COLUMNS) if c.strip()]
    where = RunFilter(scene=scene, method=method, device=device, commit=commit,
                      since=_date(since, "--since"), until=_date(until, "--until"),
                      params=parse_pairs(param, "--param", parse_json=True),
                      tags=parse_pairs(tag, "--tag"), name=name)
    store = open_store(open_settings(data_dir))
    rows = find_runs(store, where, sort=sort, limit=limit)
    if as_json:
        print_json([row.model_dump(mode="json") for row in rows])
        return
    cells = [[run_value(row, column) for column in chosen] for row in rows]
    if as_csv:
        writer = csv.writer(sys.stdout, lineterminator="\n")
        writer.writerow(chosen)
        writer.writerows([[_text(v) if isinstance(v, list | dict | datetime) else
                           ("" if v is None else v) for v in row] for row in cells])
        return
    table = Table(title=f"{len(rows)} stored runs" + (f" (the first {limit})"
                                                       if len(rows) == limit else ""))
    texts = [[_cell(column, v, row.below_noise_floor) for column, v in zip(chosen, values,
                                                                              strict=True)]
             for row, values in zip(rows, cells, strict=True)]
    for index, column in enumerate(chosen):
        header = HEADERS.get(column, column)
        if column in NUMBER_COLUMNS or column.endswith("_ci95"):
            # A number is never cut ('1.…'): its column is as wide as its widest cell.
            width = max([len(header), *(len(row[index]) for row in texts)])
            table.add_column(header, justify="right", no_wrap=True, min_width=width)
        else:
            table.add_column(header, overflow="fold")
    for row in texts:
        table.add_row(*(escape(text) for text in row))
    console.print(table)


@runs_app.command("show")
def show(run_id: RunId, as_json: JsonOut = False, data_dir: DataDir = None) -> None:
    """A run: metrics aggregated and per seed, timings, resolved method parameters and
    cache configuration, provenance, reference settings."""
    from jobs.protocol.results import RunResultDetail
    from service.tables import run_details_tables

    detail = RunResultDetail.of(_get_run(open_store(open_settings(data_dir)), run_id))
    _show(detail, as_json, run_details_tables)


@runs_app.command("compare")
def compare(
    run_ids: Annotated[list[int], typer.Argument(help="two or more run ids; the first is "
                                                      "the baseline")],
    as_json: JsonOut = False,
    data_dir: DataDir = None,
) -> None:
    """Runs side by side: what differs (settings, parameters) and each run's metrics
    against the first's, with the 95 % interval of the change where both have 3 or more
    seeds. Runs scored under different metric versions are refused."""
    from jobs.views.comparison import compare_runs
    from service.tables import comparison_table

    ids = list(dict.fromkeys(run_ids))
    if len(ids) < 2:
        raise UsageError("give two or more different run ids")
    store = open_store(open_settings(data_dir))
    comparison = compare_runs([_get_run(store, run_id) for run_id in ids])
    _show(comparison, as_json, comparison_table)


def _show(model: Any, as_json: bool, tables: Any) -> None:
    """A result as JSON, or as the tables ``tables(model)`` draws."""
    if as_json:
        print_json(model.model_dump(mode="json"))
    else:
        console.print(tables(model))


@runs_app.command("export")
def export(
    run_id: RunId,
    out: Annotated[Path, typer.Option("--out", help="folder to write the files into")],
    data_dir: DataDir = None,
) -> None:
    """Write a run's files into a folder: reference EXR and preview, per-seed EXRs,
    previews and error maps, convergence plot, summary.json."""
    from jobs.protocol.executor import RunSummary
    from jobs.protocol.spec import RenderSpec
    from jobs.views.export import export_run

    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file, not a folder")
    settings = open_settings(data_dir)
    run = _get_run(open_store(settings), run_id)
    spec = RenderSpec.model_validate(run.params["spec"])
    files = export_run(run, RunSummary.of_stored(run, spec, settings).to_json(), settings, out)
    # Each file by its name in the folder (the names docs/runs.md lists), not by its kind.
    for path in sorted(map(Path, files.values()), key=lambda path: path.name):
        console.print(f"{path.name}: {path}", markup=False, highlight=False)


@runs_app.command("tag")
def tag(
    run_id: RunId,
    name: Annotated[str | None, typer.Option("--name", help="name the run")] = None,
    set_tags: Annotated[list[str] | None, typer.Option(
        "--tag", help="KEY=VALUE tag to add (repeatable)")] = None,
    remove: Annotated[list[str] | None, typer.Option(
        "--untag", help="KEY of a tag to remove (repeatable)")] = None,
    data_dir: DataDir = None,
) -> None:
    """Name a run and add or remove its tags (find them with `runs list --name/--tag`)."""
    if name is None and not set_tags and not remove:
        raise UsageError("give --name, --tag KEY=VALUE or --untag KEY")
    run = open_store(open_settings(data_dir)).label_run(
        run_id, name=name, set_tags=parse_pairs(set_tags, "--tag"), remove_tags=remove or [])
    if run is None:
        raise UsageError(f"no run {run_id} in this data folder (see `nirc-bench runs list`)")
    tags = " ".join(f"{key}={value}" for key, value in run.tags.items()) or "-"
    console.print(f"run {run.id}: name {run.name or '-'}, tags {tags}", markup=False,
                  highlight=False)
