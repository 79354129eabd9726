"""Animated runs on the dashboard in a real headless Chromium: a run's page and its
scene's page draw the seed-mean error per frame with its band, one line per run, the
changes as labelled rules, and the recovery table. The runs are stored with synthetic
per-frame errors (tests/jobs/animation_factories.py), not rendered; the screenshot is
kept in test-artifacts/ (docs/images/dashboard_animation.png is taken from it)."""

from __future__ import annotations

import pytest

from jobs.protocol.versions import current_estimator_versions
from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.views.chart_styles import FAMILY_COLOURS
from metrics import METRIC_VERSION
from service.api.main import create_app
from tests.jobs.animation_factories import animation_metrics
from tests.jobs.factories import run_fields
from tests.service.conftest import ARTIFACTS, open_page, serve, wait_until

SCENE = "many-lights-switch"
METHODS = ("pt", "grid-cache")
#: The stroke colours of the animated chart's lines as drawn (Vega's SVG).
STROKES = ("[...document.querySelector('{} .vega-embed')"
           ".querySelectorAll('g.mark-line.role-mark path')].map(p => p.getAttribute('stroke'))")


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """pt (run 1) and grid-cache (run 2) on many-lights-switch, 18 frames of 4 seeds."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("animation-page") / "data")
    store = open_store(settings)
    versions = current_estimator_versions()
    for seed, method in enumerate(METHODS):
        animation = animation_metrics(SCENE, 18, seed=seed, steady=0.1 * (seed + 1), jump=1.5,
                                      decay_frames=1.5 + seed, noise=0.05)
        store.add_run(run_fields(scene_name=SCENE, scene_fingerprint="fp-switch", method=method,
                                 params={}, frames=18, seeds=4,
                                 estimator_version=versions[method],
                                 metric_version=METRIC_VERSION,
                                 metrics={"mrse": {"mean": 0.1}, "animation": animation}), [])
    with serve(create_app(settings)) as url:
        yield url
    store.close()


#: Chromium's console report of a request answered 404.
NOT_FOUND = "Failed to load resource: the server responded with a status of 404 (Not Found)"


def reload_counting_missing_images(page) -> list[str]:
    """Reload ``page``, listing (live) the images it asks for that the synthetic runs do
    not have (404 on a run's pixels): each is one console report, and the only one allowed."""
    missing: list[str] = []
    page.on("response", lambda r: missing.append(r.url)
            if r.status == 404 and "/pixels/" in r.url else None)
    page.reload()
    wait_until(page, "document.body.dataset.ready !== undefined")
    return missing


def test_run_page_draws_the_error_per_frame_the_labelled_changes_and_recovery(chromium, site):
    page, errors = open_page(chromium, f"{site}/#/run/1")
    errors.clear()
    missing = reload_counting_missing_images(page)
    wait_until(page, "document.querySelector('#animation table.recovery') !== null")
    figure = page.locator("#animation .vega-embed")
    assert figure.count() == 1
    assert figure.locator("g.mark-rule.role-mark line, g.mark-rule.role-mark path").count() == 2   # frames 6, 12
    labels = figure.locator("g.mark-text.role-mark text").all_text_contents()
    assert labels == ["8 lights off", "8 lights on"]
    assert figure.locator("g.mark-area.role-mark path").count() == 1                     # the band
    assert page.evaluate(STROKES.format("#animation")) == [FAMILY_COLOURS["pt"]]
    rows = page.locator("#animation table.recovery tr").all_inner_texts()[1:]
    assert [row.split("\t")[1:3] for row in rows] == [["6", "8 lights off"],
                                                      ["12", "8 lights on"]]
    ARTIFACTS.mkdir(exist_ok=True)
    page.locator("#animation").screenshot(path=str(ARTIFACTS / "dashboard-animation.png"))
    assert errors == [NOT_FOUND] * len(missing), (errors, missing)


def test_scene_page_draws_one_line_per_run_of_the_animated_scene(chromium, site):
    page, errors = open_page(chromium, f"{site}/#/scene/{SCENE}")
    wait_until(page, "document.body.dataset.ready !== undefined")
    wait_until(page, "document.querySelector('.plots.animation table.recovery') !== null")
    strokes = page.evaluate(STROKES.format(".plots.animation"))
    assert sorted(strokes) == sorted(FAMILY_COLOURS[m] for m in METHODS)
    figure = page.locator(".plots.animation .vega-embed")
    assert figure.locator("g.mark-rule.role-mark line, g.mark-rule.role-mark path").count() == 2
    assert page.locator(".plots.animation table.recovery tr").count() == 1 + 2 * len(METHODS)
    assert errors == []
