"""One public result model (jobs.protocol.results): the API, the CLI's run table (embedded
and from a service), the report's rows and the sweep's rows show a run the same way."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from rich.console import Console

from jobs.execution.apikeys import create_api_key
from jobs.protocol.executor import execute
from jobs.protocol.job import RenderJob
from jobs.protocol.results import (
    ReportRow,
    RunResult,
    RunResultDetail,
    breakdown_ms,
    device_split,
)
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


def _loaded_kernel_frames() -> list:
    """Interleaved frames (W K A W ...) whose kernel frames ran on a loaded machine: wall
    frames of 10-12 ms (render and training), kernel frames of 41-43 ms of which the
    kernels take 31-33 ms."""
    from renderers.timing import KERNEL, FrameTime, frame_kind

    frames = []
    for index in range(12):
        kind, jitter = frame_kind(index), 1e-3 * (index % 3)
        if kind == KERNEL:
            stages = {"render": 0.030 + jitter, "training": 0.010}
            frames.append(FrameTime(stages, whole_s=0.041 + jitter, kind=kind,
                                    kernel_s={"render": 0.024 + jitter, "training": 0.007}))
        else:
            frames.append(FrameTime({"render": 0.007 + jitter, "training": 0.003},
                                    whole_s=0.0105 + jitter, kind=kind))
    return frames


def test_a_runs_kernel_time_is_a_share_of_its_own_frame_time_whatever_the_kernel_frames_cost():
    """The kernel time a table shows beside a frame time is the median frame's wall time
    split by the median kernel frame's kernel shares: never above it. Planted (the old
    computation, the median kernel frame's own kernel time): 32 ms of kernels beside an
    11 ms frame, as `report` showed 404 ms of NRC kernels in a 194.8 ms frame."""
    from renderers.timing import Warmup, breakdown, kernel_frames, median_frame, summarize

    frames = _loaded_kernel_frames()
    timings = summarize(frames, Warmup())
    timings["seconds_per_frame"] = timings["frame_median_s"]
    assert timings["breakdown"]["frame_kernel_s"] > 2 * timings["seconds_per_frame"]  # old
    split = device_split(timings)
    row = ReportRow.model_construct(
        label="nrc", seconds_per_frame=timings["seconds_per_frame"],
        time_breakdown_ms=breakdown_ms(timings), kernel_breakdown_ms=split["kernel_ms"],
        harness_breakdown_ms=split["harness_ms"], kernel_seconds_per_frame=split["kernel_s"],
        harness_share=split["harness_share"])
    measured = median_frame(kernel_frames(frames), lambda f: f.kernel_total_s)
    wall = breakdown(frames)["parts_s"]
    for stage in ("render", "training"):
        share = measured.kernel_s[stage] / measured.stages[stage]
        assert row.kernel_breakdown_ms[stage] == pytest.approx(1e3 * wall[stage] * share)
        assert row.harness_breakdown_ms[stage] == pytest.approx(
            1e3 * wall[stage] * (1 - share))
    assert row.kernel_seconds_per_frame < row.seconds_per_frame
    assert row.harness_share == pytest.approx(
        1 - row.kernel_seconds_per_frame / row.seconds_per_frame)
    # Both tables: the kernel column never exceeds the wall time beside it.
    (report,) = [line.replace("│", " ").split() for line in
                 _text(breakdown_table("parts", [row])).splitlines() if "nrc" in line]
    total, kernel = map(float, report[-3:-1])
    assert kernel < total == pytest.approx(1e3 * row.seconds_per_frame, rel=1e-3)
    for line in _text(stage_table(row)).splitlines():
        cells = line.replace("│", " ").split()
        if cells and cells[0] in ("render", "training"):
            stage_wall, stage_kernel, stage_harness = map(float, cells[1:4])
            assert stage_kernel < stage_wall
            assert stage_kernel + stage_harness == pytest.approx(stage_wall, rel=1e-3)


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
