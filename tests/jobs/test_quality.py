"""Quality verdicts end to end: a scene without an emitter and a black reference are
told (and their meaningless metrics withheld), not scored; NaN pixels and untrained
caches are judged from the run's facts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from jobs.protocol.executor import execute
from jobs.protocol.job import RenderJob
from jobs.protocol.quality import judge_run
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from jobs.record.config import Settings
from jobs.record.db import open_store
from metrics import METRIC_VERSION

SCENE = """\
<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <shape type="rectangle"><bsdf type="diffuse"/></shape>
    {emitter}
</scene>
"""
# An area light off to the side that faces away from the plane and the camera.
AWAY_EMITTER = """<shape type="rectangle">
        <transform name="to_world"><rotate y="1" angle="90"/><translate x="5"/></transform>
        <emitter type="area"><rgb name="radiance" value="10"/></emitter>
    </shape>"""


@pytest.fixture
def env(mi, data_dir):
    settings = Settings()
    return settings, open_store(settings)


def _spec(path: Path) -> RenderSpec:
    return RenderSpec(scene=str(path), resolution=8, spp=1, frames=1, seeds=2,
                      reference=ReferenceSpec(spp=16, spp_per_pass=8))


def test_a_scene_without_emitter_is_told_not_scored(env, tmp_path):
    settings, store = env
    path = tmp_path / "dark.xml"
    path.write_text(SCENE.format(emitter=""))
    summary = execute(RenderJob.parse(_spec(path)), store, settings)
    run = store.get_run(summary.run_id)
    assert run.quality["verdict"] == "no-emitter"
    assert {r["code"] for r in run.quality["reasons"]} == {"no-emitter", "degenerate-reference"}
    assert set(run.quality["withheld"]) == {"mse", "mrse", "rbias2", "rvar", "flip",
                                            "efficiency", "psnr"}
    assert run.metrics["mrse_mean"] is None and run.metrics["rbias2"] is None
    assert run.metrics["psnr_mean"] is None
    assert all(s.metrics["psnr"] is None for s in run.seed_results)
    assert all(s.metrics["mrse"] is None for s in run.seed_results)
    assert run.quality["finite"] is True  # the older keys stay
    assert (run.estimator_version, run.metric_version) == (2, METRIC_VERSION)


def test_a_black_reference_is_degenerate_and_keeps_the_absolute_error(env, tmp_path):
    settings, store = env
    path = tmp_path / "away.xml"
    path.write_text(SCENE.format(emitter=AWAY_EMITTER))
    summary = execute(RenderJob.parse(_spec(path)), store, settings)
    assert summary.quality["verdict"] == "degenerate-reference"
    assert summary.metrics["mrse_mean"] is None and summary.metrics["flip_hdr_mean"] is None
    assert summary.metrics["psnr_mean"] is None     # two black tone-mapped images: 100 dB
    assert summary.metrics["mse_mean"] is not None
    assert "100 % of the reference's pixels are black" in summary.quality["reasons"][0]["message"]


def test_judged_from_facts_nan_dark_and_untrained():
    reference = np.full((10, 10, 3), 0.5, np.float32)
    image = reference.copy()
    image[0, :5] = np.nan                       # 5 of 100 pixels: above 1 %
    quality, record = judge_run([image, reference], reference, 1, [None, None])
    assert quality.verdict == "nonfinite" and "mrse" in quality.withheld
    assert record["nonfinite_fraction"] == pytest.approx(5 / 200)
    assert "5 of 200 rendered pixels (2.5 %)" in record["reasons"][0]["message"]

    dark = np.zeros((20, 20, 3), np.float32)
    dark[0, 0] = 1.0                            # 399 of 400 pixels black: above 99 %
    assert judge_run([dark], dark, 1, [None])[0].verdict == "degenerate-reference"

    stats = [{"cache_stats": {"steps": 0, "skipped_steps": 6}},
             {"cache_stats": {"steps": 4, "skipped_steps": 0}}]
    quality, record = judge_run([reference, reference], reference, 1, stats)
    assert quality.verdict == "untrained-cache" and quality.withheld == ()
    assert "1 of 2 caches" in record["reasons"][0]["message"]
