"""The dashboard's history page in a real headless Chromium: per listed metric a plot over
commits with the detected step marked, and the table of detected steps."""

from __future__ import annotations

import pytest

from jobs.record.config import Settings
from jobs.record.db import open_store
from service.api.main import create_app
from tests.service.conftest import ARTIFACTS, open_page, serve
from tests.service.test_ci_history import store_history


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """A service with eight commits of pt on cornell-box, MRSE stepping up at the fifth."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("history") / "data")
    store = open_store(settings)
    store_history(store, [0.1] * 4 + [0.13] * 4)
    with serve(create_app(settings)) as url:
        yield url
    store.close()


def test_history_page_marks_the_step(chromium, site):
    page, errors = open_page(chromium, f"{site}/#/history/cornell-box/pt")
    page.wait_for_selector("#steps table, #steps p")
    plots = page.locator("#history svg.plot")
    assert plots.count() == 5               # MRSE, FLIP, rBias², rVar, PSNR
    mrse = plots.first
    assert mrse.locator("circle").count() == 8
    assert mrse.locator("line.marker").count() == 1
    assert "step" in mrse.text_content()
    rows = page.locator("#steps tr.step")
    assert rows.count() == 1 and "c000004" in rows.first.inner_text()
    ARTIFACTS.mkdir(exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / "dashboard-history.png"), full_page=True)
    assert errors == []
