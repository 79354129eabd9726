"""The run page's comparison of two animated runs in a real headless Chromium (#/run/A/B):
per change both runs' recovery with its interval and whether they differ, per segment
both steady errors, both flickers, and both runs' error per frame on one chart with the
change as a rule; an animated run beside a static one is called not comparable. The runs
are stored with synthetic per-frame errors (tests/jobs/animation_factories.py), not
rendered; the screenshot is kept in test-artifacts/."""

from __future__ import annotations

import httpx
import numpy as np
import pytest

from jobs.protocol.flicker import run_flicker
from jobs.protocol.versions import current_estimator_versions
from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.views.chart_styles import FAMILY_COLOURS
from metrics import METRIC_VERSION
from service.api.main import create_app
from tests.jobs.animation_factories import animation_metrics
from tests.jobs.factories import run_fields
from tests.service.conftest import ARTIFACTS, open_page, serve, wait_until
from tests.service.test_dashboard_animation import (
    NOT_FOUND,
    STROKES,
    reload_counting_missing_images,
)

SCENE = "cornell-box-sudden"      # the light jumps to 4x at frame 8
FRAMES, SEEDS = 20, 6
#: (method, frames the error takes to decay, flicker per seed) of runs 1 to 3.
RUNS = (("pt", 0.5, 0.2), ("pt", 0.5, 0.2), ("grid-cache", 2.0, 0.4))


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """Runs 1 and 2 (pt) recover in ~2 frames and differ only in their noise; run 3
    (grid-cache) is a planted slow cache, ~7 frames, flickering twice as much (the draws
    of tests/service/test_runs_compare_animated.py, whose intervals tell 3 from 1 and
    not 2 from 1); run 4 is static."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("compare-animated-page") / "data")
    store = open_store(settings)
    versions = current_estimator_versions()
    rng = np.random.default_rng(7)
    for seed, (method, decay, flicker) in enumerate(RUNS):
        animation = animation_metrics(SCENE, FRAMES, seeds=SEEDS, steady=0.1, jump=3.0,
                                      decay_frames=decay, noise=0.05, seed=seed)
        animation["flicker"] = run_flicker(
            (flicker * rng.lognormal(0.0, 0.1, SEEDS)).tolist(), [0.9])
        store.add_run(run_fields(scene_name=SCENE, method=method, params={}, frames=FRAMES,
                                 seeds=SEEDS, estimator_version=versions[method],
                                 metric_version=METRIC_VERSION,
                                 metrics={"mrse": {"mean": 0.1}, "animation": animation}), [])
    store.add_run(run_fields(frames=FRAMES, seeds=SEEDS, estimator_version=versions["pt"],
                             metric_version=METRIC_VERSION), [])
    with serve(create_app(settings)) as url:
        yield url
    store.close()


def compared_page(chromium, site, baseline: int, run: int):
    """The page of ``baseline`` compared with ``run``, loaded; with its console errors
    less one 404 per image the synthetic runs do not have."""
    page, errors = open_page(chromium, f"{site}/#/run/{baseline}/{run}")
    errors.clear()
    missing = reload_counting_missing_images(page)
    return page, errors, missing


def cells(page, table: str) -> list[list[str]]:
    return [row.split("\t") for row in
            page.locator(f"table.{table} tr").all_inner_texts()[1:]]


def test_two_animated_runs_show_recovery_steady_errors_flicker_and_both_curves(chromium, site):
    page, errors, missing = compared_page(chromium, site, 1, 3)
    wait_until(page, "document.querySelector('#compare-animation .vega-embed') !== null")
    [change] = cells(page, "recovery-comparison")
    assert change[:2] == ["8", "light x4"]
    assert change[4] == "differ"                       # the planted slow cache
    assert [row[0] for row in cells(page, "steady-comparison")] == ["0–7", f"8–{FRAMES - 1}"]
    [flicker] = cells(page, "flicker-comparison")
    assert flicker[2] == "differ"                      # it flickers twice as much
    figure = page.locator("#compare-animation .vega-embed")
    assert sorted(page.evaluate(STROKES.format("#compare-animation"))) == \
        sorted(FAMILY_COLOURS[method] for method in ("pt", "grid-cache"))
    assert figure.locator("g.mark-rule.role-mark line, g.mark-rule.role-mark path").count() == 1
    ARTIFACTS.mkdir(exist_ok=True)
    page.locator("section.animation-comparison").screenshot(path=str(ARTIFACTS / "dashboard-compare-animated.png"))
    assert errors == [NOT_FOUND] * len(missing), (errors, missing)


def test_runs_that_recover_alike_do_not_differ(chromium, site):
    page, errors, missing = compared_page(chromium, site, 1, 2)
    wait_until(page, "document.querySelector('#compare-animation .vega-embed') !== null")
    [change] = cells(page, "recovery-comparison")
    assert change[4] == "no"
    assert errors == [NOT_FOUND] * len(missing), (errors, missing)


def test_an_animated_and_a_static_run_are_not_comparable(chromium, site):
    page, errors, missing = compared_page(chromium, site, 1, 4)
    wait_until(page, "document.querySelector('#comparison-note') !== null")
    assert "run 1 is animated, run 4 static" in page.locator(
        ".animation-comparison").inner_text()
    assert page.locator("table.recovery-comparison, #compare-animation").count() == 0
    assert errors == [NOT_FOUND] * len(missing), (errors, missing)


def test_the_chart_of_two_runs_answers_a_missing_run_with_404_and_a_bad_id_with_422(site):
    missing = httpx.get(f"{site}/api/v1/charts/compare/1/99")
    assert (missing.status_code, missing.json()["detail"]) == (404, "no run 99")
    assert httpx.get(f"{site}/api/v1/charts/compare/0/1").status_code == 422
    static = httpx.get(f"{site}/api/v1/charts/compare/4/1").json()
    assert static["animation"] is None and "run 1 is animated, run 4 static" in static["note"]
