"""A paper's report page in a real headless Chromium: linked from the dashboard's
navigation, it shows per figure the catalogue's claims and, where the service stored a
reproduction, our verdicts, table, its PNG beside a Vega-Lite chart per quantity and
the provenance with what it took; a figure not reproduced here says so. The screenshot
is kept in test-artifacts/. The stored reproduction is a fake figure's (synthetic
points, nothing renders)."""

from __future__ import annotations

import pytest

from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.reproduce.job import ReproduceSpec, run_reproduce
from service.api.main import create_app
from tests.service.conftest import ARTIFACTS, open_page, serve, wait_until
from tests.service.test_reproduce_jobs import fake_figure  # noqa: F401 - a fixture

JOB_ID = 7


@pytest.fixture
def site(tmp_path, monkeypatch, fake_figure):  # noqa: F811 - the imported fixture
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    settings = Settings(data_dir=tmp_path / "data")
    store = open_store(settings)
    run_reproduce(ReproduceSpec(paper="vt", figure="fig99"), store, settings, None,
                  job_id=JOB_ID)
    with serve(create_app(settings)) as url:
        yield url
    store.close()


def test_a_papers_report_page_shows_its_stored_reproduction_and_its_claims(chromium, site):
    page, errors = open_page(chromium, f"{site}/#/")
    wait_until(page, "document.body.dataset.ready !== undefined")
    page.click("nav a[href='#/papers']")
    wait_until(page, "document.body.dataset.ready === '#/papers'")
    page.click("a[href='#/paper/vt']")
    wait_until(page, "document.body.dataset.ready === '#/paper/vt'")
    stored = page.locator("section.figure[data-figure='fig99']")
    assert stored.locator(".vega-embed").count() == 1             # MRSE, its only quantity
    assert stored.locator("table.reproduction tr").count() == 3   # the head and two points
    text = stored.inner_text()
    assert "MRSE grows with x: holds" in text and f"job {JOB_ID}" in text
    assert "Provenance: commit" in text and "took wall " in text
    # The job's PNG beside the charts, loaded from the service.
    png = stored.locator(".plots img.figure-png")
    wait_until(page, "document.querySelector('img.figure-png').complete")
    assert png.evaluate("img => img.naturalWidth") == 3
    # A catalogued figure of the paper that was not run here: its claims, no table.
    catalogued = page.locator("section.figure[data-figure='fig7']")
    assert "Not reproduced on this service yet" in catalogued.inner_text()
    assert catalogued.locator("ul.claims li").count() >= 1
    ARTIFACTS.mkdir(exist_ok=True)
    stored.screenshot(path=str(ARTIFACTS / "dashboard-report.png"))
    assert errors == []
