"""The dashboard in a real headless Chromium (Debian's, driven by Playwright): the
overview, a scene page with its charts (Vega-Lite through the served vega-embed), a
run's page with the image comparison (one colour range per quantity, an uploaded EXR as
the reference), two runs compared, and the job list, with no console errors and nothing
loaded from another origin; screenshots are kept in test-artifacts/."""

from __future__ import annotations

import json
import urllib.request

import numpy as np
import pytest

from jobs.execution.apikeys import create_api_key
from jobs.execution.queue import JobQueue
from jobs.protocol.executor import execute
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from jobs.protocol.versions import current_estimator_versions
from jobs.record.config import Settings
from jobs.record.db import open_store
from metrics import METRIC_VERSION
from metrics.imageio import write_exr
from service.api.main import create_app
from tests.service.conftest import ARTIFACTS, open_page, serve, wait_until
from tests.service.test_runs_cli import SCENE_XML

SWEEP_ROWS = [{"series": series, "eps": eps, "ir_bounces_pct": 100 * (1 - eps),
               "mrse": 0.1 * scale * (1 + eps), "mrse_ci95": None, "flip": 0.3 + eps / 10,
               "rbias2": 0.01 * scale * eps, "rvar": 0.05 * scale, "ms_frame": 20.0}
              for series, scale in (("NIRC", 1.0), ("NRC", 2.0), ("NIRC equal time", 0.8))
              for eps in (0.25, 0.5, 1.0)]

#: A checksum of a canvas's displayed pixels (to see them change).
CANVAS_SUM = ("(s => {{ const c = document.querySelector(s); const d = c.getContext('2d')"
              ".getImageData(0, 0, c.width, c.height).data; let h = 0; for (let i = 0; "
              "i < d.length; i++) h = (h * 31 + d[i]) % 1000000007; return h; }})('{}')")


@pytest.fixture(scope="module")
def site(tmp_path_factory, mi):
    """A service on loopback with runs at two resolutions (16² at 1 and 2 spp, 3 seeds,
    4 frames; 24² with 1 seed, 1 frame), a run of a scene file whose settings it replaced
    (8², 1 seed), a sweep, a queued job and a finished one; and an API key."""
    folder = tmp_path_factory.mktemp("dash")
    settings = Settings(data_dir=folder / "data")
    store = open_store(settings)
    spec = RenderSpec(scene="cornell-box", resolution=16, spp=1, frames=4, seeds=3,
                      reference=ReferenceSpec(spp=64, spp_per_pass=8))
    (folder / "my-room.xml").write_text(SCENE_XML)
    runs = [execute(RenderJob.parse(s), store, settings).run_id for s in (
        spec, spec.model_copy(update={"spp": 2}),
        spec.model_copy(update={"resolution": 24, "frames": 1, "seeds": 1}),
        RenderSpec(scene=str(folder / "my-room.xml"), resolution=8, spp=1, frames=1, seeds=1,
                   reference=ReferenceSpec(spp=16, spp_per_pass=8)))]
    sweep = store.start_sweep(key="k", kind="eps", scene_name="cornell-box",
                              scene_fingerprint="f", spec={}, result={}, device_key="test",
                              estimator_versions=current_estimator_versions(),
                              metric_version=METRIC_VERSION)
    store.finish_sweep(sweep.id, status="succeeded", result={"rows": SWEEP_ROWS},
                       finished_at=None)
    queue = JobQueue(store)
    queue.submit("render", spec.model_dump(mode="json"), "queued-job")
    done, _ = queue.submit("render", spec.model_copy(update={"spp": 2}).model_dump(mode="json"),
                           "done-job")
    queue.claim(done.id, "test-worker")
    queue.succeed(done.id, run_id=runs[1])
    key = create_api_key(store, "dashboard")[1]
    with serve(create_app(settings)) as url:
        yield url, runs, key
    store.close()


def visit(chromium, url: str):
    """A page at ``url`` once the dashboard has drawn it, and its errors (open_page)."""
    page, errors = open_page(chromium, url)
    wait_until(page, "document.body.dataset.ready !== undefined")
    return page, errors


def test_overview_lists_the_latest_results_with_every_number_linked(chromium, site):
    url, runs, _ = site
    page, errors = visit(chromium, f"{url}/#/")
    assert "cornell-box" in page.inner_text("main")
    table = page.locator("h3:has-text('cornell-box') + table.results")
    assert table.locator("tr").count() == 4   # header + one per configuration
    headers = table.locator("th").all_inner_texts()
    assert headers[4:] == ["MRSE", "95% CI", "FLIP", "rBias²", "95% CI", "rVar", "95% CI",
                           "PSNR (dB)", "ms/frame", "run"]
    # Every number is a link to the run it came from.
    row = table.locator("tr").nth(1)
    links = {a.get_attribute("href") for a in row.locator("td a").all()}
    assert len(links) == 1 and links.pop() in {f"#/run/{run}" for run in runs}
    assert row.locator("td a").count() >= 8
    # A time taken on a loaded machine is marked L, with its flags as the tooltip; no
    # other time is (the site's runs: whatever this machine's load was while they ran).
    for index in range(1, table.locator("tr").count()):
        cells = table.locator("tr").nth(index).locator("td")
        run = cells.nth(cells.count() - 1).inner_text()
        flags = get_json(f"{url}/api/v1/runs/{run}")["timing_flags"]
        mark = cells.nth(cells.count() - 2).locator("b.loaded")
        assert mark.count() == (1 if flags else 0)
        if flags:
            assert mark.get_attribute("title") == "; ".join(flags)
    ARTIFACTS.mkdir(exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / "dashboard-overview.png"), full_page=True)
    assert errors == []


def test_scene_page_draws_one_group_per_setting_with_library_charts(chromium, site):
    url, runs, _ = site
    ARTIFACTS.mkdir(exist_ok=True)
    page, errors = visit(chromium, f"{url}/#/scene/cornell-box")
    groups = page.locator("#pareto section.group h4").all_inner_texts()
    assert len(groups) == 2, groups          # 16² (1 and 2 spp: one curve), 24²: never mixed
    assert sum("24×24" in g for g in groups) == 1 and sum("16×16" in g for g in groups) == 1
    # MRSE and FLIP per group, drawn by Vega (SVG with its marks), the sweep's 4 panels.
    assert page.locator("#pareto .vega-embed svg.marks").count() == 4
    assert page.locator("#sweep .vega-embed svg.marks").count() == 4
    # Hover: the tooltip shows the run's parameters; the point links to the run.
    point = page.locator("#pareto .vega-embed g.mark-symbol.role-mark path").first
    point.hover()
    wait_until(page, "document.querySelector('#vg-tooltip-element.visible') !== null")
    tip = page.inner_text("#vg-tooltip-element")
    assert "rr_survival=0.9" in tip and "run" in tip and "spp" in tip
    # docs/images/dashboard_scene.png is this screenshot (the tooltip shown, not zoomed).
    page.screenshot(path=str(ARTIFACTS / "dashboard-scene.png"), full_page=True)
    # Wheel zoom changes the axis.
    labels = ("[...document.querySelector('#pareto .vega-embed')"
              ".querySelectorAll('.role-axis-label text')].map(t => t.textContent).join()")
    before = page.evaluate(labels)
    assert before
    box = page.locator("#pareto .vega-embed svg.marks").first.bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 3)
    page.mouse.wheel(0, -400)
    wait_until(page, f"{labels} !== {json.dumps(before)}")
    assert errors == []


def test_run_page_compares_images(chromium, site):
    url, runs, _ = site
    page, errors = visit(chromium, f"{url}/#/run/{runs[0]}/{runs[2]}")
    wait_until(page, "document.getElementById('compare').dataset.ready === 'true'")
    # Reference, image, error, bias, variance of the run; image and error of the other.
    assert page.locator("#compare-grid figure > canvas").count() == 7
    assert f"run {runs[2]}: image, seed 0" in page.inner_text("#compare-grid")
    bars = page.locator(".colour-bar-label").all_inner_texts()
    assert any("relative squared error" in b for b in bars)
    assert any("relative bias" in b for b in bars) and any("relative variance" in b for b in bars)
    # The exposure changes the displayed pixels of the HDR images.
    a = CANVAS_SUM.format("#canvas-a")
    before = page.evaluate(a)
    page.evaluate("(() => { const e = document.getElementById('exposure'); e.value = '3';"
                  " e.dispatchEvent(new Event('input')); })()")
    wait_until(page, f"{a} !== {before}")
    # The slider moves the split between A and B.
    slider = page.locator("#ab")
    page.evaluate("document.getElementById('ab').value = 10")
    left = slider.screenshot()
    page.evaluate("document.getElementById('ab').value = 90")
    assert slider.screenshot() != left
    # Zoom on one image zooms every image (one transform), and the readout shows values.
    grid = page.locator("#compare-grid figure > canvas")
    other = CANVAS_SUM.format("#compare-grid figure:nth-child(3) > canvas")
    before = page.evaluate(other)
    box = grid.first.bounding_box()
    page.mouse.move(box["x"] + box["width"] / 3, box["y"] + box["height"] / 3)
    page.mouse.wheel(0, -200)
    wait_until(page, f"{other} !== {before}")
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    wait_until(page, "document.getElementById('readout').innerText.includes('pixel')")
    assert "reference" in page.inner_text("#readout")
    # What ran names the eps of its relative errors; a stage's harness share is a whole
    # percentage (the 'other' stage, all harness, read '1.0e+2').
    assert ", 3 seeds, eps 0.01 — " in page.inner_text("body")
    shares = page.locator("#timing table tr td:nth-child(5)").all_inner_texts()
    assert "100" in shares and all(s.isdigit() for s in shares), shares
    # docs/images/dashboard_comparison.png is this screenshot.
    page.screenshot(path=str(ARTIFACTS / "dashboard-compare.png"), full_page=True)
    assert errors == []


def test_a_one_seed_run_offers_no_bias_or_variance_map_and_no_convergence(chromium, site):
    url, runs, _ = site
    page, errors = visit(chromium, f"{url}/#/run/{runs[2]}")
    wait_until(page, "document.getElementById('compare').dataset.ready === 'true'")
    assert page.locator("#compare-grid figure > canvas").count() == 3
    options = page.locator("#layer-a option").all_inner_texts()
    assert options == ["reference", "image, seed 0", "error map, seed 0"]
    assert "one frame" in page.inner_text("#convergence")
    assert "24×24, 1 spp, 1 frame, online training, 1 seed, eps 0.01 — " in page.inner_text("body")
    assert errors == []


def test_job_list_shows_what_each_job_is_and_links_its_run(chromium, site):
    url, runs, _ = site
    page, errors = visit(chromium, f"{url}/#/jobs")
    page.wait_for_selector("td.status-queued")
    headers = page.locator("table.jobs th").all_inner_texts()
    for column in ("scene", "method", "spec", "submitted (UTC)", "started", "ended",
                   "duration", "state", "result"):
        assert column in headers
    done = page.locator("table.jobs tr", has=page.locator("td.status-succeeded"))
    assert "cornell-box" in done.inner_text() and "16×16, 2 spp, 4 frames, 3 seeds" in \
        done.inner_text()
    assert done.locator(f"a[href='#/run/{runs[1]}']").count() == 1
    page.screenshot(path=str(ARTIFACTS / "dashboard-jobs.png"))
    assert errors == []


def get_json(url: str):
    with urllib.request.urlopen(url) as answer:
        return json.loads(answer.read())


def test_run_page_lists_the_scene_file_settings_the_run_replaced(chromium, site):
    url, runs, _ = site
    replaced = get_json(f"{url}/api/v1/runs/{runs[3]}")["scene_overrides"]
    assert replaced, "the scene file's film, integrator and sampler are replaced"
    page, errors = visit(chromium, f"{url}/#/run/{runs[3]}")
    text = page.inner_text("main")
    assert "scene file settings not used: " + "; ".join(replaced) in text
    assert errors == []


# The ranges error maps are drawn with (set by the page as it draws them).
ERROR_RANGES = ("[...document.querySelectorAll('#compare-grid figure > canvas')]"
                ".filter(c => c.dataset.layer.includes(':error:')).map(c => c.dataset.range)")


def test_two_runs_compared_show_intervals_flags_and_one_colour_range(chromium, site):
    url, runs, _ = site
    comparison = get_json(f"{url}/api/v1/compare?runs={runs[0]},{runs[1]}")
    page, errors = visit(chromium, f"{url}/#/run/{runs[0]}/{runs[1]}")
    wait_until(page, "document.getElementById('compare').dataset.ready === 'true'")
    head = {row[0]: row[1:] for row in page.evaluate(
        "[...document.querySelectorAll('#comparison-runs tr')].map(r => "
        "[...r.cells].map(c => c.innerText))")}
    assert len(head["ms / frame"]) == 2 and "–" not in head["ms / frame"]
    for standing, efficiency, timing in zip(comparison["standings"],
                                            head["efficiency [1/s] (95% CI)"], head["timing"],
                                            strict=True):
        assert standing["efficiency_ci95"] and efficiency.count("[") == 1
        assert timing == ("; ".join(standing["timing_flags"]) or "not loaded")
    deltas = {m["metric"]: m for m in comparison["deltas"][0]["metrics"]}
    for name in ("rbias2", "rvar"):
        cells = page.locator(f"table.delta tr[data-metric='{name}'] td").all_inner_texts()
        assert cells[1].count("[") == 1 and cells[2].count("[") == 1, cells  # each run's own
        assert deltas[name]["delta_ci95"] and cells[5].startswith("["), cells   # the change's
        assert cells[6] == ("yes" if deltas[name]["differs"] else "no")
    assert comparison["note"] in page.inner_text("#comparison-note")
    # Both runs' error maps on one colour range by default, their own when asked for.
    shared = page.evaluate(ERROR_RANGES)
    assert len(shared) == 2 and shared[0] == shared[1] and shared[0]
    bars = page.locator("#compare-grid .colour-bar-label").all_inner_texts()
    assert sum("(shared range)" in b for b in bars) == 2
    page.check("#separate-ranges")
    wait_until(page, f"new Set({ERROR_RANGES}).size === 2")   # the maps' ranges differ
    assert errors == []


def test_an_uploaded_exr_is_the_reference_of_error_maps(chromium, site, tmp_path):
    url, runs, key = site
    with urllib.request.urlopen(f"{url}/api/v1/runs/{runs[0]}/pixels/reference") as answer:
        shape = [int(answer.headers[h]) for h in ("X-Height", "X-Width", "X-Channels")]
        reference = np.frombuffer(answer.read(), dtype="<f4").reshape(shape)
    write_exr(tmp_path / "small.exr", reference[:8, :8])
    write_exr(tmp_path / "brighter.exr", reference * np.float32(1.5))
    page, errors = visit(chromium, f"{url}/#/run/{runs[0]}/{runs[1]}")
    wait_until(page, "document.getElementById('compare').dataset.ready === 'true'")
    page.fill("#upload-key", key)
    page.set_input_files("#upload-file", str(tmp_path / "small.exr"))
    page.click("#upload-form button[type=submit]")
    wait_until(page, "document.getElementById('upload-status').innerText.includes('422')")
    assert "the run's images are 16x16" in page.inner_text("#upload-status")
    page.fill("#upload-key", key)
    page.set_input_files("#upload-file", str(tmp_path / "brighter.exr"))
    page.click("#upload-form button[type=submit]")
    wait_until(page, "document.getElementById('upload-status').innerText.includes('uploaded')"
                     " && document.getElementById('compare').dataset.ready === 'true'")
    grid = page.inner_text("#compare-grid")
    assert "uploaded image" in grid and "error map against the uploaded image, seed 0" in grid
    ranges = page.evaluate(ERROR_RANGES)
    assert len(ranges) == 3 and len(set(ranges)) == 1, ranges
    assert "uploaded image" in page.inner_text("#ab-caption")
    page.screenshot(path=str(ARTIFACTS / "dashboard-compare-upload.png"), full_page=True)
    # The browser logs the refused upload's 422, and nothing else.
    assert len(errors) == 1 and "status of 422" in errors[0], errors
