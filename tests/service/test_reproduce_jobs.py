"""Reproducing a figure as a service job: POST /api/v1/reproductions refuses what is not
registered (naming the choices) and a mode whose bound exceeds max_job_seconds (--full by
default), queues --quick as a ``reproduce`` job, and the job run by a runner stores the
reproduction with provenance, listed by GET /api/v1/reproductions; ``reproduce ...
--server`` submits it and prints it; ``reproduce --all`` goes on past a failing figure
and exits 1. The figures are fakes registered here: their measure returns synthetic
points, nothing renders."""

from __future__ import annotations

import sys
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
from fastapi.testclient import TestClient

from jobs.execution.apikeys import create_api_key
from jobs.execution.queue import JobQueue
from jobs.execution.runner import run_one
from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.reproduce import job as reproduce_job
from jobs.reproduce import registry
from jobs.reproduce.registry import Budget, Context, FigureSpec
from jobs.reproduce.results import Estimate, Point, Reproduction, Verdict
from metrics.imageio import png_bytes
from service.api.main import create_app
from service.cli import main
from service.client import ServiceClient

FAKE_BUDGET = Budget(resolution=4, seeds=2, frames=1, ref_spp=4, grid_preset="small",
                     why="synthetic points: nothing renders")


def _measure(ctx: Context) -> Reproduction:
    return Reproduction(
        paper="vt", figure="fig99", title="a synthetic figure", mode="",
        settings={"resolution": ctx.budget.resolution}, x_label="x",
        quantities={"mrse": "MRSE"},
        points=[Point(scene="cornell-box", series="pt", x=float(x),
                      values={"mrse": Estimate(value=0.1 * x, ci95=[0.09 * x, 0.11 * x])})
                for x in (1, 2)],
        verdicts=[Verdict(claim="MRSE grows with x", verdict="holds", reason="0.1 < 0.2")])


def _draw(reproduction: Reproduction, path: Path) -> Path:
    path.write_bytes(png_bytes(np.full((2, 3, 3), 200, np.uint8)))
    return path


@pytest.fixture
def fake_figure(monkeypatch):
    spec = FigureSpec(paper="vt", key="fig99", title="a synthetic figure",
                      budgets={"quick": FAKE_BUDGET, "full": FAKE_BUDGET},
                      measure=_measure, draw=_draw)
    monkeypatch.setitem(registry._FIGURES, ("vt", "fig99"), spec)
    return spec


def _api(tmp_path: Path, monkeypatch, **limits):
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    settings = Settings(data_dir=tmp_path / "data", **limits)
    store = open_store(settings)
    _, key = create_api_key(store, "tests")
    client = TestClient(create_app(settings, None))
    client.headers["X-API-Key"] = key
    return client, store, settings


@pytest.fixture
def api(tmp_path, monkeypatch, fake_figure):
    client, store, settings = _api(tmp_path, monkeypatch)
    yield client, store, settings
    store.close()


@pytest.mark.parametrize(("body", "field", "choices"), [
    ({"paper": "xyz", "figure": "fig1"}, "paper", "['nirc', 'nvc', 'vt']"),
    ({"paper": "vt", "figure": "fig0"}, "figure", "fig99"),
])
def test_an_unknown_paper_or_figure_is_a_422_naming_the_choices(api, body, field, choices):
    client, store, _ = api
    response = client.post("/api/v1/reproductions", json=body)
    assert response.status_code == 422, response.text
    assert field in response.text and choices in response.text
    assert JobQueue(store).list() == []


def test_quick_is_queued_and_full_is_refused_by_the_default_limit(api):
    client, store, settings = api
    quick = client.post("/api/v1/reproductions", json={"paper": "vt", "figure": "fig99"})
    assert quick.status_code == 202, quick.text
    assert quick.json()["kind"] == "reproduce" and quick.json()["spec"]["mode"] == "quick"
    full = client.post("/api/v1/reproductions",
                       json={"paper": "vt", "figure": "fig99", "mode": "full"})
    assert full.status_code == 422, full.text
    assert "max_job_seconds" in full.text and f"{settings.max_job_seconds:.0f} s" in full.text
    assert [job.spec["mode"] for job in JobQueue(store).list()] == ["quick"]


def test_full_is_queued_once_the_limit_is_raised(tmp_path, monkeypatch, fake_figure):
    """The refusal above is the limit's: the same request under a raised limit is queued."""
    client, store, _ = _api(tmp_path, monkeypatch, max_job_seconds=24 * 3600.0)
    full = client.post("/api/v1/reproductions",
                       json={"paper": "vt", "figure": "fig99", "mode": "full"})
    store.close()
    assert full.status_code == 202, full.text


def test_a_run_job_stores_the_reproduction_with_provenance(api):
    client, store, settings = api
    job_id = _run_job(client, store, settings)
    assert JobQueue(store).get(job_id).status == "succeeded"
    listed = client.get("/api/v1/reproductions", params={"paper": "vt"})
    assert listed.status_code == 200, listed.text
    [stored] = listed.json()
    assert stored["job_id"] == job_id and stored["provenance"]["job_id"] == job_id
    assert stored["provenance"]["git_commit"] and stored["provenance"]["libraries"]
    assert stored["reproduction"]["verdicts"][0]["verdict"] == "holds"
    assert [p["x"] for p in stored["reproduction"]["points"]] == [1.0, 2.0]
    assert (settings.data_dir / stored["figure_png"]).is_file()
    assert client.get("/api/v1/reproductions", params={"paper": "nvc"}).json() == []
    assert client.get("/api/v1/reproductions", params={"paper": "xyz"}).status_code == 422
    report = client.get("/api/v1/reports/vt").json()
    figures = {figure["figure"]: figure for figure in report["figures"]}
    assert figures["fig99"]["stored"]["job_id"] == job_id
    assert len(figures["fig99"]["charts"]) == 1                  # MRSE, its only quantity
    assert figures["fig7"]["stored"] is None and figures["fig7"]["claims"]
    assert client.get("/api/v1/reports/xyz").status_code == 404


def _run_job(client: TestClient, store, settings) -> int:
    job_id = client.post("/api/v1/reproductions",
                         json={"paper": "vt", "figure": "fig99"}).json()["id"]
    assert JobQueue(store).claim(job_id, "tests") is not None
    assert run_one(job_id, store, settings) == "0"
    return job_id


def test_the_figure_png_is_the_job_s_own_file_bounded_or_a_404_saying_why(api, monkeypatch):
    client, store, settings = api
    job_id = _run_job(client, store, settings)
    stored = client.get(f"/api/v1/reproductions/{job_id}").json()
    png = settings.data_dir / stored["figure_png"]
    served = client.get(stored["figure_url"])
    assert stored["figure_url"] == f"/api/v1/reproductions/{job_id}/figure.png"
    assert served.status_code == 200 and served.headers["content-type"] == "image/png"
    assert served.content == png.read_bytes()
    # A job that stored none; what is not a job id reaches no file.
    missing = client.get(f"/api/v1/reproductions/{job_id + 1}/figure.png")
    assert missing.status_code == 404 and f"job {job_id + 1} stored no reproduction" in \
        missing.json()["detail"]
    assert client.get("/api/v1/reproductions/figure/figure.png").status_code == 422
    assert client.get("/api/v1/reproductions/..%2F..%2Fdata/figure.png").status_code == 404
    # Larger than the bound: not served (the bound planted at the file's size less one).
    monkeypatch.setattr(reproduce_job, "REPRODUCTION_BYTES", png.stat().st_size - 1)
    too_large = client.get(stored["figure_url"])
    assert too_large.status_code == 404 and "larger than" in too_large.json()["detail"]
    monkeypatch.undo()
    # A link in its place is not followed, even to a PNG.
    other = png.with_name("other.png")
    png.rename(other)
    png.symlink_to(other)
    assert client.get(stored["figure_url"]).status_code == 404
    png.unlink()
    png.write_bytes(b"<svg/>")
    assert "not a PNG" in client.get(stored["figure_url"]).json()["detail"]
    png.unlink()
    gone = client.get(stored["figure_url"])
    assert gone.status_code == 404 and "gone" in gone.json()["detail"]


def test_the_cli_submits_to_a_server_and_prints_the_stored_reproduction(
        api, monkeypatch, capsys):
    """``--server``: the job is submitted over REST, run (here by a runner in the test,
    as the service's dispatcher would) and the stored reproduction printed."""
    client, store, settings = api

    def connect(self: ServiceClient, server: str, api_key: str | None) -> None:
        self.http = client

    def run_then_read(self: ServiceClient, job_id: int, progress=None) -> dict:
        assert JobQueue(store).claim(job_id, "tests") is not None
        assert run_one(job_id, store, settings) == "0"
        return self.get(f"/api/v1/jobs/{job_id}")

    monkeypatch.setattr(ServiceClient, "__init__", connect)
    monkeypatch.setattr(ServiceClient, "wait", run_then_read)
    argv = ["nirc-bench", "reproduce", "vt", "fig99", "--server", "http://service"]
    with mock.patch.object(sys, "argv", argv), pytest.raises(SystemExit) as exit_info:
        main()
    text = capsys.readouterr().out
    assert exit_info.value.code == 0, text
    assert "MRSE grows with x: **holds**" in text and "job 1" in text
    assert "its PNG: http://service/api/v1/reproductions/1/figure.png" in text
    assert [job.kind for job in JobQueue(store).list()] == ["reproduce"]


def _failing(ctx: Context) -> Reproduction:
    raise RuntimeError("a planted failure")


def test_reproduce_all_goes_on_past_a_failing_figure_and_exits_1(
        tmp_path, monkeypatch, capsys, fake_figure):
    failing = FigureSpec(paper="vt", key="fig01", title="a failing figure",
                         budgets={"quick": FAKE_BUDGET, "full": FAKE_BUDGET},
                         measure=_failing, draw=_draw)
    monkeypatch.setattr(registry, "_FIGURES", {("vt", "fig01"): failing,
                                               ("vt", "fig99"): fake_figure})
    monkeypatch.setattr(registry, "figure_modules", lambda: [])
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    argv = ["nirc-bench", "reproduce", "--all", "--quick", "--data-dir", str(tmp_path)]
    with mock.patch.object(sys, "argv", argv), pytest.raises(SystemExit) as exit_info:
        main()
    text = capsys.readouterr().out
    assert exit_info.value.code == 1, text
    assert "1 of 2 figures reproduced" in text
    assert "vt fig01: FAILED (RuntimeError: a planted failure)" in text
    assert "vt fig99: MRSE grows with x: holds" in text   # run after the failing one
    assert (tmp_path / "reproduce" / "vt-fig99" / "table.json").is_file()
