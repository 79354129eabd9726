"""No silent successes: each degenerate case, rendered end to end
through the executor on a tiny XML scene, is stored with a named verdict and its
meaningless metrics withheld (None), or refused at load with a SceneError naming the
shape; one case each through the CLI (--json) and the REST API. Also the inf finding of
docs/estimators.md ("Infinite scales and radiance: pt and path")."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from jobs.protocol.executor import execute
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from jobs.record.config import Settings
from jobs.record.db import open_store
from renderers.scenes.errors import SceneError
from renderers.scenes.loader import load_scene
from service.api.main import create_app
from tests.service.test_cli import run_cli

# A diffuse floor lit by a small spherical area light; {floor} goes into the floor's
# shape, {light} into the light's transform, {radiance} is the light's.
SCENE = """\
<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <shape type="rectangle" id="floor"><bsdf type="diffuse"/>{floor}</shape>
    <shape type="sphere" id="lamp">
        <transform name="to_world"><scale value="0.3"/><translate x="0.5" y="0.5" z="1"/>{light}</transform>
        <emitter type="area"><rgb name="radiance" value="{radiance}"/></emitter>
    </shape>
</scene>
"""
ERRORS = {"mse", "mrse", "rbias2", "rvar", "flip", "efficiency", "psnr"}  # every error metric


def scene(tmp_path: Path, name: str, radiance: str = "5", floor: str = "",
          light: str = "") -> Path:
    path = tmp_path / f"{name}.xml"
    path.write_text(SCENE.format(radiance=radiance, floor=floor, light=light))
    return path


def spec(path: Path, method: str = "pt", frames: int = 1) -> RenderSpec:
    return RenderSpec(scene=str(path), method=method, resolution=8, spp=1, frames=frames,
                      seeds=2, reference=ReferenceSpec(spp=16, spp_per_pass=8))


@pytest.fixture
def env(mi, data_dir):
    settings = Settings()
    store = open_store(settings)
    yield settings, store
    store.close()


def stored(store, summary):
    run = store.get_run(summary.run_id)
    assert run.status == "succeeded"
    return run


def test_a_cache_that_never_trained_says_how_many_steps_were_skipped_and_why(env, tmp_path):
    # 1e18: the reference stays finite, but every training loss overflows float32.
    settings, store = env
    summary = execute(RenderJob.parse(spec(scene(tmp_path, "bright", radiance="1e18"), "nrc", frames=2)),
                      store, settings)
    run = stored(store, summary)
    assert run.quality["verdict"] == "untrained-cache"
    message = run.quality["reasons"][0]["message"]
    assert "2 of 2 caches took no successful training step" in message
    assert "all 24 steps they tried were skipped because the loss or its gradients were " \
           "NaN or infinite" in message
    assert [s.metrics["method_stats"]["cache_stats"]["steps"] for s in run.seed_results] \
        == [0, 0]


def test_an_overflowing_reference_is_nonfinite_not_an_empty_ok(env, tmp_path):
    # 1e30: the reference mean is finite, its variance (1e60) is not: before, the run
    # was "ok" with MSE and MRSE silently None.
    settings, store = env
    summary = execute(RenderJob.parse(spec(scene(tmp_path, "huge", radiance="1e30"))), store, settings)
    run = stored(store, summary)
    assert run.quality["verdict"] == "nonfinite"
    assert set(run.quality["withheld"]) == ERRORS
    assert "64 of 64 reference pixels (in 64 of them the reference's variance overflowed" \
        in run.quality["reasons"][0]["message"]
    assert run.metrics["mrse_mean"] is None and run.metrics["flip_hdr_mean"] is None
    assert all(s.metrics["mse"] is None for s in run.seed_results)


def test_negative_radiance_is_told_not_hidden_as_a_black_reference(env, tmp_path):
    # Before, negative pixels counted as black: the verdict was degenerate-reference.
    settings, store = env
    summary = execute(RenderJob.parse(spec(scene(tmp_path, "negative", radiance="-1"))), store, settings)
    run = stored(store, summary)
    assert run.quality["verdict"] == "negative-radiance"
    assert run.quality["withheld"] == ["flip"]
    assert [r["code"] for r in run.quality["reasons"]] == ["negative-radiance"]
    assert run.metrics["flip_hdr_mean"] is None and run.metrics["mrse_mean"] is not None


@pytest.mark.parametrize(("floor", "light"), [
    ('<transform name="to_world"><scale value="nan"/></transform>', ""),
    ('<transform name="to_world"><matrix value="1 0 0 0 0 nan 0 0 0 0 1 0 0 0 0 1"/>'
     "</transform>", ""),
    ("", '<scale value="inf"/>'),
])
def test_a_non_finite_transform_is_refused_at_load_naming_the_shape(mi, tmp_path, floor,
                                                                     light):
    # Before, Mitsuba dropped the shape silently and the run was "ok".
    path = scene(tmp_path, "vanishing", floor=floor, light=light)
    with pytest.raises(SceneError, match="NaN or infinite transform") as refused:
        load_scene(str(path), 8)
    assert ("shape id='floor'" if floor else "shape id='lamp'") in str(refused.value)


def test_an_infinite_emitter_is_refused_at_load_naming_it(mi, tmp_path):
    with pytest.raises(SceneError, match="infinite 'radiance'") as refused:
        load_scene(str(scene(tmp_path, "inf", radiance="inf, 1, 1")), 8)
    assert "shape id='lamp'" in str(refused.value)


def test_a_black_reference_is_degenerate(env, tmp_path):
    settings, store = env
    # The lamp sits far outside the view, behind the floor: everything seen is black.
    path = scene(tmp_path, "dark", light='<translate z="-50"/>')
    run = stored(store, execute(RenderJob.parse(spec(path)), store, settings))
    assert run.quality["verdict"] == "degenerate-reference"
    assert run.metrics["mrse_mean"] is None and run.metrics["mse_mean"] is not None


def test_the_cli_json_and_the_api_carry_the_verdict(mi, tmp_path, monkeypatch):
    data = tmp_path / "data"
    monkeypatch.setenv("NIRC_BENCH_DATA_DIR", str(data))
    monkeypatch.delenv("NIRC_BENCH_DATABASE_URL", raising=False)
    path = scene(tmp_path, "negative", radiance="-1")
    proc = run_cli("render", "--scene", str(path), "--res", "8", "--spp", "1", "--seeds", "2",
                   "--ref-spp", "16", "--json", data_dir=data)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["quality"]["verdict"] == "negative-radiance"
    assert summary["metrics"]["flip_hdr_mean"] is None
    with TestClient(create_app(Settings(data_dir=data))) as http:
        run = http.get(f"/api/v1/runs/{summary['run_id']}").json()
    assert run["verdict"] == "negative-radiance" and run["withheld"] == ["flip"]

    refused = run_cli("render", "--scene", str(scene(tmp_path, "nan", floor=(
        '<transform name="to_world"><scale value="nan"/></transform>'))), "--res", "8",
        "--json", data_dir=data)
    assert refused.returncode != 0 and "Traceback" not in refused.stderr
    assert "shape id='floor'" in " ".join((refused.stderr + refused.stdout).split())


INF_SCENE = """\
<scene version="3.0.0">
    <integrator type="{integrator}"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="16"/></sampler>
        <film type="hdrfilm"><rfilter type="box"/>
            <integer name="width" value="16"/><integer name="height" value="16"/></film>
    </sensor>
    <shape type="rectangle"><bsdf type="diffuse"/></shape>
    <shape type="sphere">
        <transform name="to_world"><scale value="0.3"/><translate x="0.5" y="0.5" z="1"/></transform>
        <emitter type="area"><rgb name="radiance" value="{radiance}"/></emitter>
    </shape>
    {extra}
</scene>
"""


@pytest.mark.parametrize(("radiance", "extra", "expected"), [
    # An inf-scaled shape: both drop it (never hit), no non-finite pixel in either.
    ("5", '<shape type="cube"><transform name="to_world"><scale value="inf"/></transform>'
          "</shape>", 0),
    # An emitter of inf radiance: inf * 0 (NEE at grazing angles, zero BSDF values) is
    # NaN in both, in the same pixels.
    ("inf", "", None),
])
def test_pt_and_path_agree_on_non_finite_pixels(mi, radiance, extra, expected):
    from renderers.integrators.path import PLUGIN_NAME, register

    register()
    counts, masks = {}, {}
    for integrator in ("path", PLUGIN_NAME):
        loaded = mi.load_string(INF_SCENE.format(integrator=integrator, radiance=radiance,
                                                 extra=extra), optimize=False)
        image = np.asarray(mi.render(loaded, seed=1))[..., :3]
        masks[integrator] = ~np.isfinite(image).all(axis=-1)
        counts[integrator] = int(masks[integrator].sum())
    assert counts[PLUGIN_NAME] == counts["path"]
    assert np.array_equal(masks[PLUGIN_NAME], masks["path"])
    if expected is not None:
        assert counts["path"] == expected
    else:
        assert counts["path"] > 0
