"""`pt` agrees with Mitsuba's built-in `path` in expectation (per-pixel z-test).

The procedure of Mitsuba 3's render tests: per-pixel means and variances of
both images from all their samples (``moment`` integrator), a two-sided
z-test per pixel and channel, and a Šidák correction so that the whole image
is tested at significance alpha = 1 %. Our `pt` uses a fixed-probability
Russian roulette (survival 0.9) while `path` uses a throughput-based one, so
the two draw different samples and agree only if both are unbiased.

Every comparison runs both the per-pixel test and the aggregate test over
pixel tiles (``agreement_test``), which catches biases of a few percent that
no single pixel shows. The power tests show the procedure can fail: a path
tracer missing bounces (max_depth 3 against 8) is rejected, and so is a 2 %
brighter reference, which the per-pixel test alone lets through. The null
test counts false rejections over independent pairs of unbiased renders.
"""

from __future__ import annotations

import pytest

from metrics.statistics import agreement_test
from tests.support.moments import render_moments

pytestmark = pytest.mark.slow

RES = 24
#: Samples per pixel of each side of the agreement tests. The planted missing bounces
#: (max_depth 3) are rejected at this spp with a wide margin: 1425 of 1728
#: pixel-channels below the Šidák level, aggregate mean z -37.8 (measured).
SPP = 2048
MAX_DEPTH = 8


def _pt(**params):
    from renderers.integrators import path

    path.register()
    return {"type": path.PLUGIN_NAME, "max_depth": MAX_DEPTH, **params}


def _agreement(scene, test_integrator, seed=0):
    mean_a, var_a = render_moments(scene, test_integrator, SPP, seed=seed + 1)
    mean_b, var_b = render_moments(scene, {"type": "path", "max_depth": MAX_DEPTH}, SPP,
                                   seed=seed + 1000)
    return agreement_test(mean_a, var_a, mean_b, var_b, alpha=0.01)


@pytest.mark.parametrize("name", ["cornell-box", "cornell-glossy", "sky", "door"])
def test_pt_matches_mitsuba_path(mi, name):
    from renderers.scenes import load_scene

    scene = load_scene(name, RES).scene
    result = _agreement(scene, _pt())
    assert result.passed, result.summary()


def test_pt_throughput_roulette_matches_mitsuba_path(mi):
    from renderers.scenes import load_scene

    scene = load_scene("cornell-box", RES).scene
    result = _agreement(scene, _pt(rr_mode="throughput", rr_depth=2))
    assert result.passed, result.summary()


def test_pt_matches_on_xml_scene(mi, tmp_path):
    from renderers.scenes import load_scene

    xml = tmp_path / "scene.xml"
    xml.write_text(XML_SCENE)
    scene = load_scene(str(xml), RES).scene
    result = _agreement(scene, _pt(rr_survival=0.5, rr_depth=1))
    assert result.passed, result.summary()


def test_z_test_rejects_a_path_tracer_missing_bounces(mi):
    """The test has power: truncating paths at 3 segments (instead of 8) is caught."""
    from renderers.scenes import load_scene

    scene = load_scene("cornell-box", RES).scene
    result = _agreement(scene, _pt(max_depth=3))
    print(result.summary())
    assert not result.passed, result.summary()


def test_agreement_rejects_a_two_percent_bias_the_per_pixel_test_misses(mi):
    from renderers.scenes import load_scene

    # 1024 spp: a 2 % shift is about half a standard deviation per pixel.
    scene = load_scene("cornell-box", RES).scene
    mean_a, var_a = render_moments(scene, _pt(), 1024, seed=1)
    mean_b, var_b = render_moments(scene, {"type": "path", "max_depth": MAX_DEPTH}, 1024,
                                   seed=1000)
    planted = agreement_test(mean_a, var_a, 1.02 * mean_b, 1.02**2 * var_b, alpha=0.01)
    assert planted.per_pixel.passed and not planted.aggregate.passed, planted.summary()


def test_false_rejections_of_unbiased_pairs_are_rare(mi):
    """Ten independent pairs (our pt against Mitsuba's path, 16x16, 512 spp): at
    alpha 0.01 per pair, two or more rejections happen with probability < 0.5 %."""
    from renderers.scenes import load_scene

    scene = load_scene("cornell-box", 16).scene
    rejected = []
    for pair in range(10):
        mean_a, var_a = render_moments(scene, _pt(), 512, seed=10 + 2 * pair)
        mean_b, var_b = render_moments(scene, {"type": "path", "max_depth": MAX_DEPTH}, 512,
                                       seed=11 + 2 * pair)
        result = agreement_test(mean_a, var_a, mean_b, var_b, alpha=0.01)
        if not result.passed:
            rejected.append(result.summary())
    assert len(rejected) <= 1, rejected


XML_SCENE = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world">
            <lookat origin="0, 1, 4" target="0, 0.5, 0" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm">
            <integer name="width" value="32"/>
            <integer name="height" value="32"/>
            <rfilter type="box"/>
            <string name="pixel_format" value="rgb"/>
        </film>
        <sampler type="independent"/>
    </sensor>
    <bsdf type="diffuse" id="grey">
        <rgb name="reflectance" value="0.6, 0.6, 0.6"/>
    </bsdf>
    <shape type="rectangle">
        <transform name="to_world">
            <rotate x="1" angle="-90"/>
            <scale value="3"/>
        </transform>
        <ref id="grey"/>
    </shape>
    <shape type="sphere">
        <point name="center" value="0, 0.5, 0"/>
        <float name="radius" value="0.5"/>
        <bsdf type="roughconductor">
            <float name="alpha" value="0.2"/>
        </bsdf>
    </shape>
    <shape type="sphere">
        <point name="center" value="1, 2.5, 1"/>
        <float name="radius" value="0.3"/>
        <emitter type="area">
            <rgb name="radiance" value="20, 18, 15"/>
        </emitter>
    </shape>
    <emitter type="constant">
        <rgb name="radiance" value="0.1, 0.12, 0.2"/>
    </emitter>
</scene>
"""
