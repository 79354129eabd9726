"""Progressive references: stopping rules, variance image, split-half floor."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from renderers.reference import ReferenceSettings, render_reference
from tests.renderers.scene_xml import perspective_sensor

#: A floor lit by a small area light of radiance 1e30 (both seen by the camera).
BLINDING = """<scene version="3.0.0">
    """ + perspective_sensor("60", "0, 2, 3", "0, 0, 0", res="8") + """
    <shape type="rectangle"><transform name="to_world"><scale value="2"/>
        <rotate x="1" angle="-90"/></transform><bsdf type="diffuse"/></shape>
    <shape type="rectangle"><transform name="to_world"><scale value="0.3"/>
        <rotate x="1" angle="90"/><translate y="1"/></transform>
        <emitter type="area"><rgb name="radiance" value="1e30, 1e30, 1e30"/></emitter></shape>
</scene>
"""


@pytest.fixture(scope="module")
def scene(mi):
    from renderers.scenes import load_scene

    return load_scene("cornell-box", 16).scene


def test_stops_at_the_target_spp(scene):
    ref = render_reference(scene, ReferenceSettings(spp=256, spp_per_pass=32), seed_parts=("t",))
    assert ref.spp == 256 and ref.passes == 8
    assert ref.mean.shape == ref.variance.shape == (16, 16, 3)
    assert np.all(ref.variance >= 0) and np.all(np.isfinite(ref.mean))


def test_stops_early_at_the_target_relative_standard_error(scene):
    loose = ReferenceSettings(spp=1 << 14, spp_per_pass=16, rel_stderr=0.2, min_passes=8)
    ref = render_reference(scene, loose, seed_parts=("t",))
    assert ref.passes == 8  # the minimum number of passes already meets 0.2
    assert ref.rel_stderr <= 0.2


def test_few_spp_still_gives_enough_passes_for_a_variance(scene):
    ref = render_reference(scene, ReferenceSettings(spp=16, spp_per_pass=64, min_passes=8),
                           seed_parts=("t",))
    assert ref.passes == 8 and ref.spp == 16


def test_variance_image_predicts_the_error_between_two_references(scene):
    """Two independent references differ by what their variance images predict.

    Per pixel, (A - B)^2 / (var_A + var_B) has expectation 1; its mean over the
    768 pixel-channels is compared (a plain ratio of means would be dominated by
    the few pixels with rare bright paths).
    """
    settings = ReferenceSettings(spp=512, spp_per_pass=16)
    a = render_reference(scene, settings, seed_parts=("a",))
    b = render_reference(scene, settings, seed_parts=("b",))
    normalized = (a.mean.astype(np.float64) - b.mean) ** 2 / (a.variance + b.variance)
    assert 0.75 < np.mean(normalized) < 1.3


def test_split_half_floor_matches_the_variance_image(scene):
    ref = render_reference(scene, ReferenceSettings(spp=1024, spp_per_pass=16), seed_parts=("c",))
    floor = ref.split_half
    assert floor["reference_mrse_estimate"] == pytest.approx(floor["half_vs_half_mrse"] / 4)
    predicted = np.mean(ref.variance / (ref.mean.astype(np.float64) ** 2 + 0.01))
    # Loose: both sides are dominated by the few pixels with rare bright paths.
    assert 0.3 < floor["reference_mrse_estimate"] / predicted < 3.0


def test_a_variance_beyond_float32_is_infinite_without_an_overflowing_cast(mi):
    """Where a 1e30 emitter lights the floor, the variance of the pixel's mean (up to
    ~1e55) exceeds float32's 3.4e38: it is kept as +inf, which the readers take as overflowed,
    the mean stays finite, and no cast overflows (a RuntimeWarning before)."""
    scene = mi.load_string(BLINDING)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        ref = render_reference(scene, ReferenceSettings(spp=16, spp_per_pass=2),
                               seed_parts=("blinding",))
    assert np.isfinite(ref.mean).all() and ref.mean.max() > 1e25
    assert np.isposinf(ref.variance).any() and not np.isnan(ref.variance).any()
    assert ref.variance.dtype == np.float32


@pytest.mark.parametrize("settings", [
    ReferenceSettings(integrator="bogus"),
    ReferenceSettings(max_depth=0),
    ReferenceSettings(spp=4),
    ReferenceSettings(rel_stderr=0.0),
    ReferenceSettings(min_passes=1),
])
def test_invalid_settings_are_rejected(settings):
    with pytest.raises(ValueError):
        settings.validate()
