"""The dashboard's history page in a real headless Chromium: per listed metric one chart
per setting (scene, resolution, frames, protocol, device), one line per run label and spp,
the detected step marked, and the table of detected steps."""

from __future__ import annotations

from datetime import timedelta

import pytest

from jobs.record.config import Settings
from jobs.record.db import open_store
from service.api.main import create_app
from tests.jobs.factories import run_fields
from tests.service.conftest import ARTIFACTS, open_page, serve, wait_until
from tests.service.test_ci_history import START, store_history


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """Eight commits of pt on cornell-box: at 64² with max_depth 8 (MRSE stepping up at
    the fifth) and max_depth 4 (flat), at 32² (flat), and at 64² on another device; two
    commits of pt on door whose rBias² is below 0 (below the noise floor) and whose MRSE
    was not stored."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("history") / "data")
    store = open_store(settings)
    store_history(store, [0.1] * 4 + [0.13] * 4)
    store_history(store, [0.2] * 8, seed=1, params={"max_depth": 4})
    store_history(store, [0.3] * 8, seed=2, width=32, height=32)
    store_history(store, [0.4] * 8, seed=3, device_key="llvm:other-cpu")
    for i, rbias2 in enumerate((-0.001, -0.0002)):
        store.add_run(run_fields(scene_name="door", git_commit=f"d{i:06d}",
                                 created_at=START + timedelta(hours=i),
                                 metrics={"rbias2": rbias2}), [])
    with serve(create_app(settings)) as url:
        yield url
    store.close()


def test_history_page_draws_a_chart_per_setting_and_marks_the_step(chromium, site):
    page, errors = open_page(chromium, f"{site}/#/history/cornell-box/pt")
    wait_until(page, "document.body.dataset.ready !== undefined")
    mrse = page.locator("#history section").first
    assert mrse.locator("h4").inner_text() == "MRSE"
    charts = mrse.locator(".vega-embed")
    assert charts.count() == 3                  # 64² and 32², 64² on another device
    titles = [charts.nth(i).locator(".role-title-text").text_content() for i in range(3)]
    assert sum("32×32" in t for t in titles) == 1
    assert sum("64×64" in t and "llvm:other-cpu" in t for t in titles) == 1
    wide = charts.nth(next(i for i, t in enumerate(titles) if "64×64" in t and "test-cpu" in t))
    legend = wide.locator(".role-legend-label text").all_text_contents()
    assert sorted(legend) == ["pt (max_depth 4), 1 spp", "pt (max_depth 8), 1 spp"]
    assert wide.locator("g.mark-symbol.role-mark path").count() == 16
    assert wide.locator("g.mark-rule path, g.mark-rule line").count() >= 1   # the step
    # Hover a point: its commit, median and runs.
    wide.locator("g.mark-symbol.role-mark path").first.hover()
    wait_until(page, "document.querySelector('#vg-tooltip-element.visible') !== null")
    assert "c000000" in page.inner_text("#vg-tooltip-element")
    rows = page.locator("#steps tr.step")
    assert rows.count() == 1 and "c000004" in rows.first.inner_text()
    assert rows.first.locator("a[href^='#/run/']").count() >= 1
    ARTIFACTS.mkdir(exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / "dashboard-history.png"), full_page=True)
    assert errors == []


def test_history_page_says_when_every_median_is_below_the_noise_floor(chromium, site):
    """rBias² whose every median is below 0 has no chart on its log axis: the page says
    they are below the noise floor, not that there is no value (as it does for MRSE,
    which none of these runs stored)."""
    page, errors = open_page(chromium, f"{site}/#/history/door/pt")
    wait_until(page, "document.body.dataset.ready !== undefined")
    sections = {s.locator("h4").inner_text(): s for s in page.locator("#history section").all()}
    rbias2, mrse = sections["rBias²"], sections["MRSE"]
    assert rbias2.locator(".vega-embed").count() == 0
    assert rbias2.locator("p.muted").inner_text() == (
        "Every median of rBias² of pt on door (2) is at or below 0, below the noise floor: "
        "none can be drawn on its log axis.")
    assert mrse.locator("p.muted").inner_text().startswith("No value of MRSE")
    assert errors == []
