"""Light selection as one object of the PT core (renderers.integrators.lights).

The selectors' own invariants (pmfs sum to 1, ``sample`` returns the pmf that
``pmf`` gives, emitter pointers map to indices, environment emitters are
selectable) are checked directly. The statistical tests compare `pt-power`
and `pt-spatial` on `many-lights` (32 small lights behind partitions) with
Mitsuba's built-in ``path`` (same ``max_depth``) by ``agreement_test``
(per-pixel Šidák z-test and aggregate block test), on the luminance channel
only as in tests/renderers/test_estimators.py. Each comes with twins the same
procedure must reject: the spatial selector's pmf used for NEE but Mitsuba's
uniform pmf in the MIS weight of BSDF-sampled hits (the inconsistency one
selection object rules out), and a 3 % brighter reference. The last test
measures what light selection is for: lower per-pixel variance than uniform
selection at the same sample count.
"""

from __future__ import annotations

import numpy as np
import pytest

from metrics.statistics import agreement_test
from tests.renderers.lighting import (
    ENV_AND_SPHERE,
    RES,
    SPP,
    luminance_moments,
    pt_integrator,
    random_points,
)
from tests.support.moments import render_moments

MAX_DEPTH = 4
PLANTED = 1.03  # a 3 % brighter reference


def _integrator(mi, sampler_type=None, max_depth=MAX_DEPTH):
    return pt_integrator(mi, sampler_type, max_depth)



@pytest.fixture(scope="module")
def many_lights(mi):
    from renderers.scenes import load_scene

    return load_scene("many-lights", RES).scene


# ---------------------------------------------------------------------------
# The selectors' invariants (fast)
# ---------------------------------------------------------------------------

def _selectors():
    from renderers.integrators import lights

    return [lights.UniformLightSampler, lights.PowerLightSampler, lights.SpatialLightSampler]


@pytest.mark.parametrize("index", range(3), ids=["uniform", "power", "spatial"])
def test_pmfs_sum_to_one_and_sample_returns_its_pmf(mi, many_lights, index):
    sampler = _selectors()[index](many_lights)
    si, rng = random_points(mi, many_lights)
    count = len(many_lights.emitters())
    total = sum(sampler.pmf(si, mi.UInt32(i), True).numpy() for i in range(count))
    np.testing.assert_allclose(total, 1.0, rtol=1e-5)
    chosen, pmf, u_reused = sampler.sample(si, mi.Float(rng.uniform(size=64)), True)
    np.testing.assert_allclose(pmf.numpy(), sampler.pmf(si, chosen, True).numpy(), rtol=1e-5)
    assert np.all((u_reused.numpy() >= 0) & (u_reused.numpy() < 1))


def test_emitter_pointers_map_to_their_index(mi, many_lights):
    import drjit as dr

    from renderers.integrators.lights import PowerLightSampler

    sampler = PowerLightSampler(many_lights)
    count = len(many_lights.emitters())
    pointers = dr.gather(mi.EmitterPtr, many_lights.emitters_dr(), mi.UInt32(np.arange(count)))
    assert sampler.index_of(pointers, True).numpy().tolist() == list(range(count))


def test_spatial_selector_prefers_the_light_overhead(mi, many_lights):
    """30 cm below a light, that light is the likeliest (the others are >= 1 m away
    and at most ~2.5x as powerful)."""
    from renderers.integrators.lights import SpatialLightSampler

    sampler = SpatialLightSampler(many_lights)
    si, _ = random_points(mi, many_lights, count=1)
    for index, emitter in enumerate(many_lights.emitters()):
        centre = emitter.bbox().center()
        si.p = mi.Point3f(centre[0], centre[1] - 0.3, centre[2])
        pmfs = [sampler.pmf(si, mi.UInt32(i), True).numpy()[0] for i in range(32)]
        assert int(np.argmax(pmfs)) == index


def test_environment_emitters_are_selectable(mi):
    """An environment is one of the emitters: positive power and pmf at every point."""
    from renderers.integrators.lights import SpatialLightSampler, emitter_powers

    scene = mi.load_string(ENV_AND_SPHERE.format(res=RES))
    powers = emitter_powers(scene)
    assert powers.shape == (2,) and np.all(powers > 0)
    sampler = SpatialLightSampler(scene)
    si, _ = random_points(mi, scene)
    pmfs = np.stack([sampler.pmf(si, mi.UInt32(i), True).numpy() for i in range(2)])
    assert np.all(pmfs > 0)
    np.testing.assert_allclose(pmfs.sum(axis=0), 1.0, rtol=1e-5)


def test_methods_are_registered_with_pt_parameters():
    from renderers.methods import METHODS, MethodError, parse_params

    for name in ("pt-power", "pt-spatial"):
        assert parse_params(name, {"max_depth": 4}).max_depth == 4
        with pytest.raises(MethodError, match="max_depth"):
            parse_params(name, {"max_depth": 0})
        assert METHODS[name].version == 1


def test_default_selector_is_mitsubas(mi, many_lights):
    """`pt` keeps the scene's own routines: the same NEE samples as Scene's."""
    from renderers.integrators.lights import UniformLightSampler

    integrator = _integrator(mi)
    assert isinstance(integrator.light_sampler(many_lights), UniformLightSampler)
    assert integrator.light_sampler(many_lights) is integrator.light_sampler(many_lights)


# ---------------------------------------------------------------------------
# Agreement with Mitsuba's path on many-lights, and the planted twins (slow)
# ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def reference(mi, many_lights):
    return luminance_moments(render_moments(many_lights, {"type": "path", "max_depth": MAX_DEPTH}, SPP,
                             seed=1000))


@pytest.fixture(scope="module")
def spatial(mi, many_lights):
    from renderers.integrators.lights import SpatialLightSampler

    return luminance_moments(render_moments(many_lights, _integrator(mi, SpatialLightSampler), SPP, seed=1))


@pytest.mark.slow
def test_power_selection_matches_mitsuba_path(mi, many_lights, reference):
    from renderers.integrators.lights import PowerLightSampler

    test = luminance_moments(render_moments(many_lights, _integrator(mi, PowerLightSampler), SPP, seed=2))
    result = agreement_test(*test, *reference, alpha=0.01)
    assert result.passed, result.summary()


@pytest.mark.slow
def test_spatial_selection_matches_mitsuba_path(spatial, reference):
    result = agreement_test(*spatial, *reference, alpha=0.01)
    assert result.passed, result.summary()


@pytest.mark.slow
def test_spatial_selection_against_a_brighter_reference_is_rejected(spatial, reference):
    mean, var = reference
    result = agreement_test(*spatial, mean * PLANTED, var * PLANTED**2, alpha=0.01)
    assert not result.passed, result.summary()


@pytest.mark.slow
def test_spatial_nee_with_uniform_mis_pmf_is_rejected(mi, many_lights, reference):
    """Two selection objects that disagree: NEE samples with the spatial pmf, the MIS
    weight of BSDF-sampled hits uses Mitsuba's uniform pmf. The MIS weights no
    longer sum to 1 and the image is biased."""
    from renderers.integrators.lights import SpatialLightSampler

    class UniformPdfForMIS(SpatialLightSampler):
        def pdf_emitter_direction(self, prev_si, ds, active):
            return self.scene.pdf_emitter_direction(prev_si, ds, active)

    test = luminance_moments(render_moments(many_lights, _integrator(mi, UniformPdfForMIS), SPP, seed=3))
    result = agreement_test(*test, *reference, alpha=0.01)
    assert not result.passed, result.summary()


@pytest.mark.slow
def test_spatial_selection_lowers_per_pixel_variance(mi, many_lights, spatial):
    """The point of light selection: at equal spp, the median per-pixel variance
    of `pt-spatial` is well below that of uniform selection (measured ~0.25)."""
    uniform = luminance_moments(render_moments(many_lights, _integrator(mi), SPP, seed=4))
    ratio = float(np.median(spatial[1] / uniform[1]))
    print(f"median per-pixel variance ratio spatial / uniform: {ratio:.3f}")
    assert ratio < 0.5, ratio


@pytest.mark.slow
def test_spatial_selection_with_an_environment_matches_mitsuba_path(mi):
    """An environment (constant) and an area light (sphere): both selected, both MIS-weighted."""
    from renderers.integrators.lights import SpatialLightSampler

    scene = mi.load_string(ENV_AND_SPHERE.format(res=RES))
    test = luminance_moments(render_moments(scene, _integrator(mi, SpatialLightSampler), 1024, seed=5))
    reference = luminance_moments(render_moments(scene, {"type": "path", "max_depth": MAX_DEPTH}, 1024,
                                  seed=1005))
    result = agreement_test(*test, *reference, alpha=0.01)
    assert result.passed, result.summary()


@pytest.mark.parametrize("index", [1, 2], ids=["power", "spatial"])
def test_a_scene_without_emitters_renders_black(mi, index):
    """Found by the stress suite (docs/stress.md): with no emitter, the power selector
    built an empty distribution and the MIS pdf indexed an empty weight list; both
    crashed the render. Now NEE and the MIS pdf add nothing and the image is 0."""
    from tests.renderers.scene_xml import perspective_sensor

    scene = mi.load_string(f"""<scene version="3.0.0">
        {perspective_sensor("45", "0, 0, 3", "0, 0, 0").replace("{res}", "8")}
        <shape type="rectangle"><bsdf type="diffuse"/></shape>
    </scene>""")
    integrator = _integrator(mi, _selectors()[index])
    image = np.array(mi.render(scene, integrator=integrator, spp=4))
    assert np.all(image[..., :3] == 0)
