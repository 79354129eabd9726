"""Adaptive termination (NIRC paper Sec. 6.3): the per-pixel v1 mask reaches the right
lanes, and the paper's exclusions (delta lobes for NIRC, roughness < 0.0625 for NRC)
hold. Termination statistics only: the cache's values do not matter here."""

from __future__ import annotations

import numpy as np
import pytest

from renderers.methods import parse_params

RES = 16


def _film(scene, integrator, spp=1, seed=0):
    import mitsuba as mi

    return np.asarray(mi.render(scene.scene, integrator=integrator, spp=spp, seed=seed))


def _adaptive(method: str, scene):
    from renderers.methods import nirc, nrc

    build = {"nirc": nirc.build, "nrc": nrc.build}[method]
    params = {"max_depth": 8, "termination": "adaptive"}
    if method == "nirc":
        params["estimator"] = "biased"
    integrator, _trainer, cache = build(scene, parse_params(method, params), 3)
    integrator.cache = cache
    return integrator


@pytest.mark.parametrize("res, spp", [(8, 1), (13, 3), (RES, 4)])
def test_lane_to_pixel_layout_of_mitsuba_wavefronts(mi, res, spp):
    """The mask lookup relies on Mitsuba's wavefront being pixel-major (lane // spp)."""
    from renderers.integrators.cached import pixel_index
    from renderers.scenes import load_scene

    class PixelIndex(mi.SamplingIntegrator):
        def aov_names(self):
            return ["pixel"]

        def sample(self, scene, sampler, ray, medium=None, active=True):
            return mi.Spectrum(0), mi.Bool(True), [mi.Float(pixel_index(ray, sampler))]

    mi.register_integrator("test_pixel_index", lambda props: PixelIndex(props))
    scene = load_scene("cornell-box", res)
    film = _film(scene, mi.load_dict({"type": "test_pixel_index"}), spp=spp)
    np.testing.assert_array_equal(film[..., 3].ravel(), np.arange(res * res))


def test_nirc_terminates_at_v1_exactly_where_the_mask_allows(mi):
    from renderers.scenes import load_scene

    scene = load_scene("cornell-box", RES)  # diffuse and rough plastic: no delta lobes
    integrator = _adaptive("nirc", scene)
    mask = np.zeros((RES, RES), bool)
    mask[:, : RES // 2] = True
    integrator.set_v1_mask(mask)
    film = _film(scene, integrator)
    depth, cache_depth = film[..., 3], film[..., 4]   # AOVs: depth, cache_depth, ...
    hit = depth >= 1
    assert hit[mask].mean() > 0.9
    np.testing.assert_array_equal(cache_depth[mask & hit], 1)
    assert not np.any(cache_depth[~mask] == 1)
    # Outside the mask later vertices stop by the spread heuristic (mostly at v2).
    assert np.mean(cache_depth[~mask & hit] == 2) > 0.5

    integrator.set_v1_mask(None)  # no mask: every pixel may use the cache at v1
    film = _film(scene, integrator)
    np.testing.assert_array_equal(film[..., 4][film[..., 3] >= 1], 1)


def test_nrc_is_not_used_at_v1_on_too_glossy_surfaces(mi):
    """cornell-glossy's small box is rough plastic with alpha 0.05 < 0.0625: NRC never
    terminates there at v1, NIRC (glossy is not delta) does."""
    from renderers.integrators.cached import cache_inputs
    from renderers.scenes import load_scene

    class FirstHitRoughness(mi.SamplingIntegrator):
        def aov_names(self):
            return ["roughness"]

        def sample(self, scene, sampler, ray, medium=None, active=True):
            si = scene.ray_intersect(ray)
            roughness = dr.select(si.is_valid(), cache_inputs(si, si.bsdf(ray))["roughness"], -1)
            return mi.Spectrum(0), mi.Bool(True), [roughness]

    import drjit as dr

    mi.register_integrator("test_first_hit_roughness", lambda props: FirstHitRoughness(props))
    scene = load_scene("cornell-glossy", RES)
    roughness = _film(scene, mi.load_dict({"type": "test_first_hit_roughness"}))[..., 3]
    glossy = (roughness >= 0) & (roughness < 0.0625)
    assert glossy.sum() >= 4
    assert np.allclose(roughness[glossy], 0.05)
    nrc_v1 = _film(scene, _adaptive("nrc", scene))[..., 4] == 1
    nirc_v1 = _film(scene, _adaptive("nirc", scene))[..., 4] == 1
    assert not nrc_v1[glossy].any()
    assert nirc_v1[glossy].all()
    assert nrc_v1[~glossy & (roughness >= 0)].mean() > 0.9


def test_mask_shape_is_checked(mi):
    from renderers.scenes import load_scene

    scene = load_scene("cornell-box", RES)
    integrator = _adaptive("nrc", scene)
    with pytest.raises(ValueError, match="height, width"):
        integrator.set_v1_mask(np.ones(RES * RES, bool))
    integrator.set_v1_mask(np.ones((RES, RES + 1), bool))
    with pytest.raises(Exception):  # noqa: B017 - Mitsuba wraps the integrator's ValueError
        _film(scene, integrator)
