"""The scene page's error-vs-time charts in a real headless Chromium: runs of one setting
at several spp are one chart, each method configuration one curve through its spp, every
curve its own colour, the Pareto front black, the strongest PT grey; the screenshot is kept in test-artifacts/
(docs/images/dashboard_pareto.png is taken from it)."""

from __future__ import annotations

import pytest

from jobs.protocol.executor import execute
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from jobs.record.config import Settings
from jobs.record.db import open_store
from jobs.views.chart_styles import ENVELOPE_STYLE, FAMILY_COLOURS, FRONT_COLOUR
from service.api.main import create_app
from tests.service.conftest import ARTIFACTS, open_page, serve, wait_until

#: (method, parameters, spp): the paper's PT at 1, 2 and 4 spp, PT with throughput
#: roulette and pt-power (two candidates of the strongest PT) at 1 and 2.
POINTS = [("pt", {}, spp) for spp in (1, 2, 4)] + \
    [(method, {"rr_mode": "throughput"}, spp) for method in ("pt", "pt-power") for spp in (1, 2)]
CURVES = ["pt", "pt (rr_mode throughput)", "pt-power (rr_mode throughput)"]
#: The fill colours of the first chart's points (the runs).
FILLS = ("[...document.querySelector('#pareto .vega-embed')"
         ".querySelectorAll('g.mark-symbol.role-mark path')].map(p => p.getAttribute('fill'))"
         ".filter(f => f && f !== 'transparent' && f !== 'none')")
#: The stroke colours of a chart's lines as drawn (Vega's SVG), by the chart's index.
STROKES = ("[...document.querySelectorAll('#pareto .vega-embed')[{}]"
           ".querySelectorAll('g.mark-line path')].map(p => p.getAttribute('stroke'))")


@pytest.fixture(scope="module")
def site(tmp_path_factory, mi):
    """A service with seven 8² runs of cornell-box (1 seed, 2 frames) at three spp."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("pareto-page") / "data")
    store = open_store(settings)
    reference = ReferenceSpec(spp=32, spp_per_pass=8)
    for method, params, spp in POINTS:
        execute(RenderJob.parse(RenderSpec(scene="cornell-box", method=method, params=params,
                                           resolution=8, spp=spp, frames=2, seeds=1,
                                           reference=reference)), store, settings)
    with serve(create_app(settings)) as url:
        yield url
    store.close()


def test_one_chart_per_setting_one_curve_per_configuration_and_a_black_front(chromium, site):
    page, errors = open_page(chromium, f"{site}/#/scene/cornell-box")
    wait_until(page, "document.body.dataset.ready !== undefined")
    groups = page.locator("#pareto section.group")
    assert groups.count() == 1, groups.all_inner_texts()    # spp is no group
    charts = groups.first.locator(".vega-embed")
    assert charts.count() == 2                                # MRSE and FLIP
    mrse = charts.first
    assert "spp" not in mrse.locator(".role-title-text").first.text_content()
    fills = page.evaluate(FILLS)
    assert len(fills) == len(POINTS), fills                   # one dot per run
    legend = set(mrse.locator(".role-legend-label text").all_text_contents())
    strokes = page.evaluate(STROKES.format(0))
    assert FRONT_COLOUR in strokes                            # the front, black
    # The strongest PT, grey, wherever a candidate's curve has two points on its own
    # front (times of such tiny frames are noisy: 2 spp may not be slower than 1).
    envelope = ENVELOPE_STYLE.colour in strokes
    assert sorted(legend) == sorted(CURVES + ["strongest PT"] * envelope)
    curves = [s for s in strokes if s not in (FRONT_COLOUR, ENVELOPE_STYLE.colour)]
    assert len(curves) == len(CURVES) == len(set(curves)), strokes
    assert FAMILY_COLOURS["pt"] in curves and FAMILY_COLOURS["pt-power"] in curves
    ARTIFACTS.mkdir(exist_ok=True)
    groups.first.screenshot(path=str(ARTIFACTS / "dashboard-pareto.png"))
    assert errors == []
