"""One public result model (jobs.protocol.results): the API, the CLI's run table (embedded
and from a service), the report's rows and the sweep's rows show a run the same way."""

from __future__ import annotations

from fastapi.testclient import TestClient
from rich.console import Console

from jobs.execution.apikeys import create_api_key
from jobs.protocol.executor import execute
from jobs.protocol.job import RenderJob
from jobs.protocol.results import ReportRow, RunResult, RunResultDetail
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.sweeps.sweep import point_row
from service.api.main import create_app
from service.tables import breakdown_table, metrics_table, stage_table

SPEC = RenderSpec(scene="cornell-box", resolution=8, spp=1, frames=2, seeds=2,
                  reference=ReferenceSpec(spp=64, spp_per_pass=8))


def _text(renderable) -> str:
    console = Console(width=250, record=True)
    console.print(renderable)
    return console.export_text()


def test_every_view_of_a_run_is_the_one_result_model(mi, data_dir):
    settings = Settings()
    store = open_store(settings)
    summary = execute(RenderJob.parse(SPEC), store, settings)
    run = store.get_run(summary.run_id)
    row = RunResult.of(run)
    assert summary.result == RunResultDetail.of(run)   # what the executor hands the CLI

    _, key = create_api_key(store, "tests")
    with TestClient(create_app(settings, None)) as client:
        client.headers["X-API-Key"] = key
        listed = client.get("/api/v1/results").json()
        detail = client.get(f"/api/v1/runs/{run.id}").json()
    assert [RunResult.model_validate(item) for item in listed] == [row]
    served = RunResultDetail.model_validate(detail)
    assert served == summary.result
    # The CLI prints a run from a service exactly as it prints it embedded.
    assert _text(metrics_table(served)) == _text(metrics_table(summary.result))

    shared = set(RunResult.model_fields)
    report_row = ReportRow.model_validate({**summary.result.model_dump(), "label": "PT"})
    sweep_row = point_row("pt", None, run)
    for view in (report_row, sweep_row):
        assert view.model_dump(include=shared) == row.model_dump(include=shared)
    assert row.render_seconds_per_frame is not None and row.seconds_per_frame is not None
    # The Table-1 breakdown reaches the run table and the report's breakdown table.
    assert set(row.time_breakdown_ms) == {"render", "other"}
    assert "the median frame by stage" in _text(metrics_table(summary.result))
    report_text = _text(breakdown_table("parts", [report_row]))
    assert "render" in report_text and "other" in report_text and "PT" in report_text


def test_the_stage_table_takes_a_stages_harness_from_the_kernel_frame_alone():
    """A kernel frame that does far more work than the wall frames (300 ms of kernels in
    330 ms beside 11-ms wall frames): its harness is 30 ms, 9 % of it, where the wall
    frame's time less the kernel frame's kernels would read -289 ms."""
    run = RunResult.model_construct(
        time_breakdown_ms={"render": 11.0}, kernel_breakdown_ms={"render": 300.0},
        harness_breakdown_ms={"render": 30.0})
    row = next(line for line in _text(stage_table(run)).splitlines() if "render" in line)
    assert row.replace("│", " ").split() == ["render", "11", "300", "30", "9", "-"], row


def test_a_runs_resolved_cache_configuration_is_served(api_and_store):
    """What a run's ``caches`` shows: the stored resolved configuration of its seeds
    (method_stats['caches']), or for a run stored before it the config and training
    budget it kept apart; nothing for a method without a cache."""
    from tests.jobs.factories import run_fields

    http, store = api_and_store
    resolved = {"cache": {"config": {"mlp": {"width": 64, "hidden_layers": 4}},
                          "per_frame": {"steps": 4, "batch_size": 1024, "records": 4096}}}
    stored = [
        {"method_stats": {"caches": resolved}},
        {"method_stats": {"cache_config": resolved["cache"]["config"],
                          "training_budget": resolved["cache"]["per_frame"]}},
        {"method_stats": {}},
    ]
    for method_stats, expected in zip(stored, (resolved, resolved, {}), strict=True):
        run = store.add_run(run_fields(method="nirc", params={"cache": {}}),
                            [{"seed": 0, "metrics": method_stats, "timings": {}}])
        served = http.get(f"/api/v1/runs/{run.id}").json()
        assert served["caches"] == expected and served["params"]["cache"] == {}
        assert served["params"]["nc"] == [4]    # served resolved: BTH's default N_c
