"""``nirc-bench ci`` end to end: runners (embedded or over REST), baseline, outputs, exit code.

The comparison runs here in the client (jobs.ci.ci); only the runs
themselves go to a service with ``--server``, which stores them like any job.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console

from jobs.ci.ci import (
    BaselineSource,
    Runner,
    baseline_rows,
    file_baseline,
    run_suite,
    stored_baseline,
)
from jobs.ci.ci_suite import CiError, load_suite, read_baseline, write_baseline
from jobs.protocol.job import RenderJob
from jobs.protocol.results import RunResultDetail
from jobs.record.store import Store
from service.ci_report import headline, junit, markdown


@dataclass(frozen=True)
class CiOptions:
    """The options of the command (service.cli.ci)."""

    suite: Path
    baseline: Path
    baseline_ref: str | None
    update_baseline: bool
    seed_start: int
    summary: Path | None
    junit: Path | None
    data_dir: Path | None
    server: str | None
    api_key: str | None
    #: Run the suite's soak (``[soak]``) after the gate (embedded runs only).
    soak: bool = True


def embedded_runner(data_dir: Path | None) -> tuple[Runner, Store]:
    """Runs each job in this process through the executor; also returns the store."""
    from jobs.protocol.executor import execute
    from jobs.record.config import Settings
    from jobs.record.db import open_store

    settings = Settings(data_dir=data_dir) if data_dir else Settings()
    store = open_store(settings)
    return (lambda job: execute(job, store, settings).result), store


def remote_runner(server: str, api_key: str | None) -> Runner:
    """Submits each job's spec to the service at ``server`` (which parses it at its own
    entry) and reads the stored run back."""
    from service.client import RemoteError, ServiceClient

    client = ServiceClient(server, api_key)

    def run(render: RenderJob) -> RunResultDetail:
        job = client.wait(client.submit("render", render.spec.model_dump(mode="json"))["id"])
        if job["status"] != "succeeded":
            raise RemoteError(f"job {job['id']} {job['status']}: {job['error']}")
        return RunResultDetail.model_validate(client.get(f"/api/v1/runs/{job['run_id']}"))

    return run


def run_ci(options: CiOptions, console: Console, err_console: Console) -> int:
    """Run the command; the exit status: 0 pass (or baseline written), 1 regression.
    Anything that keeps it from running raises (the caller exits 2)."""
    suite = load_suite(options.suite)
    if options.update_baseline and options.baseline_ref:
        raise CiError("--update-baseline writes the baseline file; it takes no --baseline-ref")
    store: Store | None = None
    if options.server:
        if options.baseline_ref:
            raise CiError("--baseline-ref reads the local database; with --server compare "
                          "with a baseline file (--baseline)")
        runner = remote_runner(options.server, options.api_key)
    else:
        runner, store = embedded_runner(options.data_dir)

    def progress(text: str) -> None:
        err_console.print(f"nirc-bench ci: {text}", markup=False, highlight=False)

    if options.update_baseline:
        rows = baseline_rows(suite, runner, seed_start=options.seed_start, progress=progress)
        write_baseline(options.baseline, rows)
        console.print(f"baseline written to {options.baseline} ({len(rows)} rows)",
                      markup=False, highlight=False)
        return 0
    source: BaselineSource
    if options.baseline_ref:
        source, name = stored_baseline(store, options.baseline_ref), options.baseline_ref
    else:
        source, name = file_baseline(read_baseline(options.baseline).rows), str(options.baseline)
    result = run_suite(suite, runner, source, suite_name=str(options.suite),
                       baseline_name=name, seed_start=options.seed_start, progress=progress)
    text = markdown(result)
    soak_problems: list[str] = []
    if suite.soak is not None and options.soak and store is not None:
        soak_text, soak_problems = run_soak_of(suite.soak, store, options.data_dir, progress)
        text += "\n\n" + soak_text
    console.print(text, markup=False, highlight=False, soft_wrap=True)
    for path, content in ((options.summary, text), (options.junit, junit(result))):
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(content)
    err_console.print(f"nirc-bench ci: {headline(result)}", markup=False, highlight=False)
    for problem in soak_problems:
        err_console.print(f"nirc-bench ci: soak: {problem}", markup=False, highlight=False,
                          soft_wrap=True)
    return max(result.exit_code, 1 if soak_problems else 0)


def run_soak_of(wanted: dict[str, int], store: Store, data_dir: Path | None,
                progress: Callable[[str], None]) -> tuple[str, list[str]]:
    """The suite's soak (jobs.stress.soak) through the CLI's own render: its table and
    its problems."""
    from pydantic import ValidationError

    from jobs.execution.embedded import render_here
    from jobs.protocol.scene_store import builtin_features
    from jobs.record.config import Settings
    from jobs.stress.soak import SoakSettings, markdown_table, run_soak

    try:
        settings = SoakSettings(**wanted)
    except ValidationError as err:
        raise CiError(f"the suite's [soak]: {err.errors()[0]['msg']}") from None
    paths = Settings(data_dir=data_dir) if data_dir else Settings()
    report = run_soak(lambda job: render_here(job, store, paths), builtin_features, settings,
                      progress=lambda what: progress(f"soak: {what}"))
    return markdown_table(report), report.problems()
