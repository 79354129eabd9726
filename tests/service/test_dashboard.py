"""The dashboard in a real headless Chromium (Debian's, driven by Playwright): the
overview, a scene page and the job list render their tables, plots and images with
no console errors; screenshots are kept in test-artifacts/."""

from __future__ import annotations

import pytest

from jobs.execution.queue import JobQueue
from jobs.protocol.executor import execute
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from jobs.protocol.versions import current_estimator_versions
from jobs.record.config import Settings
from jobs.record.db import open_store
from metrics import METRIC_VERSION
from service.api.main import create_app
from tests.service.conftest import ARTIFACTS, open_page, serve, wait_until

SWEEP_ROWS = [{"series": series, "eps": eps, "ir_bounces_pct": 100 * (1 - eps),
               "mrse": 0.1 * scale * (1 + eps), "mrse_ci95": None, "flip": 0.3 + eps / 10,
               "rbias2": 0.01 * scale * eps, "rvar": 0.05 * scale, "ms_frame": 20.0}
              for series, scale in (("NIRC", 1.0), ("NRC", 2.0), ("NIRC equal time", 0.8))
              for eps in (0.25, 0.5, 1.0)]


@pytest.fixture(scope="module")
def site(tmp_path_factory, mi):
    """A service on loopback with two runs (one with 4 frames), a sweep and a job."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("dash") / "data")
    store = open_store(settings)
    spec = RenderSpec(scene="cornell-box", resolution=16, spp=1, frames=4, seeds=2,
                      reference=ReferenceSpec(spp=64, spp_per_pass=8))
    execute(RenderJob.parse(spec), store, settings)
    execute(RenderJob.parse(spec.model_copy(update={"spp": 2})), store, settings)
    sweep = store.start_sweep(key="k", kind="eps", scene_name="cornell-box",
                              scene_fingerprint="f", spec={}, result={}, device_key="test",
                              estimator_versions=current_estimator_versions(),
                              metric_version=METRIC_VERSION)
    store.finish_sweep(sweep.id, status="succeeded", result={"rows": SWEEP_ROWS},
                       finished_at=None)
    JobQueue(store).submit("render", spec.model_dump(mode="json"), "queued-job")
    with serve(create_app(settings)) as url:
        yield url
    store.close()


def test_overview_lists_the_latest_results(chromium, site):
    page, errors = open_page(chromium, f"{site}/#/")
    page.wait_for_selector("table td")
    assert "cornell-box" in page.inner_text("main")
    assert page.locator("table tr").count() >= 3   # header + pt 1 spp + pt 2 spp
    assert page.locator("td.verdict").first.inner_text() == "ok"
    # The metric columns are the registry's listed metrics (GET /api/v1/metrics), PSNR included.
    headers = page.locator("table").first.locator("th").all_inner_texts()
    assert headers[3:] == ["MRSE", "95% CI", "FLIP", "rBias²", "rVar", "PSNR (dB)", "ms/frame",
                           "run"]
    ARTIFACTS.mkdir(exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / "dashboard-overview.png"))
    assert errors == []


def test_scene_page_draws_plots_and_images(chromium, site):
    page, errors = open_page(chromium, f"{site}/#/scene/cornell-box")
    wait_until(page, "document.querySelectorAll('svg.plot').length >= 7")
    plots = page.locator("svg.plot")
    # Error vs time (MRSE and FLIP, one device), 4 sweep panels, convergence: each has
    # drawn points, not "no data"; the error-vs-time plots mark the Pareto front.
    pareto = page.locator("#pareto svg.plot")
    assert pareto.count() == 2
    assert all("Pareto front" in pareto.nth(i).text_content() for i in range(2))
    for i in range(plots.count()):
        assert plots.nth(i).locator("circle").count() > 0, plots.nth(i).inner_text()
    wait_until(page,
        "[...document.querySelectorAll('#images img')].every(i => i.complete && i.naturalWidth > 0)")
    assert page.locator("#images img").count() == 3      # reference, method, error map
    # The run's median frame by stage: wall, kernel and harness milliseconds.
    page.wait_for_selector("table.timing td")
    timing = page.locator("table.timing")
    assert timing.locator("th").all_inner_texts() == ["stage", "wall ms", "kernel ms",
                                                      "harness ms", "harness %", "launches"]
    stages = timing.locator("tr td.text").all_inner_texts()
    assert stages[0] == "render" and stages[-1] == "other"
    assert "harness share" in page.inner_text("#timing")
    page.locator(".crop").first.click()                 # crop: all images zoom together
    assert "scale(4)" in page.locator("#images img").first.get_attribute("style")
    page.screenshot(path=str(ARTIFACTS / "dashboard-scene.png"), full_page=True)
    assert errors == []


def test_job_list_shows_live_status(chromium, site):
    page, errors = open_page(chromium, f"{site}/#/jobs")
    page.wait_for_selector("td.status-queued")
    page.screenshot(path=str(ARTIFACTS / "dashboard-jobs.png"))
    assert errors == []
