"""What every command module of the CLI shares: its consoles, common options, the store."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

# Tables are wide: when the output is not a terminal (a log, a pipe, CI), do not wrap at
# 80 columns: wide enough that the sweep table keeps its rows whole.
# No emoji codes: 'a:b:step' is text, not ':b:'.
console = Console(width=None if sys.stdout.isatty() else 220, emoji=False)
err_console = Console(stderr=True, emoji=False)

DataDir = Annotated[
    Path | None,
    typer.Option("--data-dir", help="data folder (database, references, artifacts)",
                 envvar="NIRC_BENCH_DATA_DIR"),
]
JsonOut = Annotated[bool, typer.Option("--json", help="print JSON instead of a table")]
#: The reference's spp unless --ref-spp says otherwise: ReferenceSpec's default
#: (jobs/protocol/spec.py), one for every command; written out here so that the CLI
#: starts without importing the specs.
REF_SPP = 4096
RefSpp = Annotated[int, typer.Option("--ref-spp", min=8, max=1 << 24,
                                     help="spp of the converged reference")]


def number_in(low: float, high: float = math.inf) -> Callable[[Any], float]:
    """The parser of a float option whose value lies in [low, high]. Its refusals say
    what is wrong: 'nan' is not a number, 'inf' not a finite one (a bare range check
    reads NaN as above the maximum: "less than or equal to 1"). The option's help
    states the range (a parser hides Typer's)."""
    def parse(value: Any) -> float:
        from pydantic_core import PydanticCustomError  # read by Typer's option check

        def refuse(why: str) -> PydanticCustomError:
            return PydanticCustomError("option_value", "'{value}' " + why, {"value": value})

        try:
            number = float(value)
        except (TypeError, ValueError):
            raise refuse("is not a number") from None
        if math.isnan(number):
            raise refuse("is not a number")
        if math.isinf(number):
            raise refuse("is not a finite number")
        if not low <= number <= high:
            raise refuse(f"is not in [{low:g}, {high:g}]" if math.isfinite(high)
                         else f"is below {low:g}")
        return number

    return parse


def open_settings(data_dir: Path | None) -> Any:
    """The settings, with ``data_dir`` when given (else the environment's or ./data);
    UsageError when the data folder is a file."""
    from jobs.record.config import Settings
    from service.errors import UsageError

    settings = Settings(data_dir=data_dir) if data_dir else Settings()
    if settings.data_dir.exists() and not settings.data_dir.is_dir():
        raise UsageError(f"the data folder {settings.data_dir} is a file, not a folder "
                         "(--data-dir or NIRC_BENCH_DATA_DIR)")
    return settings


def open_store(settings: Any) -> Any:
    """The store of ``settings`` (migrated to the current schema)."""
    from jobs.record.db import open_store as open_db

    return open_db(settings)


def print_json(value: Any) -> None:
    """``value`` as indented JSON on standard output (dates and paths as text)."""
    console.print_json(json.dumps(value, default=str))


Server = Annotated[str | None, typer.Option(
    "--server", envvar="NIRC_BENCH_SERVER",
    help="submit to a running service (e.g. http://host:8000) instead of running here")]
ApiKeyOpt = Annotated[str | None, typer.Option(
    "--api-key", envvar="NIRC_BENCH_API_KEY", help="API key for --server")]


def submit_and_wait(client: Any, kind: str, spec: dict[str, Any], server: str,
                    as_json: bool) -> dict[str, Any]:
    """Submit a ``kind`` job of ``spec`` through ``client`` (service.client.ServiceClient),
    follow its progress and return the finished job; RemoteError unless it succeeded."""
    from service.client import RemoteError
    from service.progress import progress_reporter

    job = client.submit(kind, spec)
    if not as_json:
        console.print(f"job {job['id']} submitted to {server} ({job['status']})")
    with progress_reporter(console, quiet=as_json) as report:
        job = client.wait(job["id"], progress=report)
    if job["status"] != "succeeded":
        raise RemoteError(f"job {job['id']} {job['status']}: {job['error']}")
    return job
