"""`ss-nirc`: the screen-space key, unbiasedness with power, a planted bias, memory.

The two-level estimator at the primary hits (NIRC paper Eq. 10-12) with a trained
per-pixel latent table must agree with Mitsuba's ``path`` under the per-pixel Šidák
z-test and the block test (metrics.statistics.agreement_test). Power: the cache term
carries most of the first hits' indirect light (its share is checked), so the planted
defect — the residual's factor -f cos / p scaled by 0.5, i.e. half of the cache
term left uncorrected — moves every lit pixel by about L_c / 2 and must be rejected.
"""

from __future__ import annotations

import numpy as np
import pytest

from metrics.statistics import agreement_test
from renderers.methods import get_method, parse_params
from tests.support.moments import render_moments

RES, DEPTH, SPP, TRAIN_FRAMES = 8, 4, 256, 6
#: A small network and latent (the estimator's unbiasedness does not depend on the
#: capacity; the default 74 floats and 6 x 64 layers train 4x slower here).
SMALL = {"preset": "small", "screen_latent": {"features": 8}}


@pytest.fixture(scope="module")
def cornell(mi):
    from renderers.scenes import load_scene

    return load_scene("cornell-box", RES)


@pytest.fixture(scope="module")
def trained(cornell):
    """(integrator, cache, params) of SS NIRC trained for TRAIN_FRAMES frames."""
    from renderers.methods import ss_nirc
    from renderers.methods.budget import TrainingBudget
    from renderers.methods.cached import train_once
    from renderers.timing import StageTimer

    params = parse_params("ss-nirc", {"max_depth": DEPTH, "cache": SMALL})
    integrator, trainer, cache = ss_nirc.build(cornell, params, seed=7)
    integrator.cache = trainer.cache = cache
    budget = TrainingBudget("paper", paths=2048, steps=4, batch_size=2048)
    for frame in range(TRAIN_FRAMES):
        train_once(cache, trainer, cornell, budget, seed=frame, timer=StageTimer())
    return integrator, cache, params


def test_the_key_is_the_pixel_of_the_primary_hit(mi, cornell):
    """Primary hits of rays through pixel centres project back to their own pixel."""
    import drjit as dr

    from renderers.caches.screen import ScreenProjection

    sensor = cornell.scene.sensors()[0]
    index = dr.arange(mi.UInt32, RES * RES)
    x, y = index % RES, index // RES
    centre = mi.Point2f((mi.Float(x) + 0.5) / RES, (mi.Float(y) + 0.5) / RES)
    ray, _ = sensor.sample_ray(0.0, 0.5, centre, mi.Point2f(0.5))
    si = cornell.scene.ray_intersect(ray)
    pixel = ScreenProjection(sensor).pixel(si.p)
    hit = np.asarray(si.is_valid())
    assert hit.mean() > 0.9
    np.testing.assert_array_equal(np.asarray(pixel)[hit], np.asarray(index)[hit])


def test_ss_nirc_agrees_with_the_reference_and_a_planted_bias_is_rejected(mi, cornell,
                                                                          trained):
    integrator, cache, params = trained
    reference = render_moments(cornell.scene, {"type": "path", "max_depth": DEPTH}, SPP, seed=2)
    result = agreement_test(*render_moments(cornell.scene, integrator, SPP, seed=1), *reference)
    assert result.passed, result.summary()

    # Power: with the residual's cache part dropped the render gains E[L_c], which must
    # be most of what the first hits reflect beyond their direct light.
    integrator.residual_weight = lambda vertex: 0.0 * vertex.bsdf_weight
    uncorrected, _ = render_moments(cornell.scene, integrator, SPP, seed=3)
    direct, _ = render_moments(cornell.scene, {"type": "path", "max_depth": 2}, SPP, seed=4)
    share = (uncorrected - reference[0]).sum() / (reference[0] - direct).sum()
    assert share > 0.5, f"the cache term holds {share:.2f} of the indirect light"

    integrator.residual_weight = lambda vertex: -0.5 * vertex.bsdf_weight
    try:
        planted = agreement_test(*render_moments(cornell.scene, integrator, SPP, seed=5),
                                 *reference)
    finally:
        del integrator.residual_weight
    assert not planted.passed


def test_a_render_is_reproducible_and_stores_its_memory(mi, cornell):
    from tests.support.untimed import UNTIMED

    method = get_method("ss-nirc")
    params = parse_params("ss-nirc", {"max_depth": DEPTH, "min_train_paths": 256,
                                      "cache": {**SMALL, "screen_latent": {"features": 16}}})
    a, b = (method.render(cornell, params, seed_parts=("ss",), spp=1, frames=2, hooks=UNTIMED)
            for _ in range(2))
    np.testing.assert_array_equal(a.accumulated, b.accumulated)
    assert a.method_stats["model"]["floats_per_pixel"] == {"model": 16, "training": 48}
    assert a.method_stats["cache_stats"]["steps"] > 0
    # The cache is used at the primary hit alone.
    assert 0 < a.path_stats["avg_cache_vertices"] <= 1


@pytest.mark.parametrize("values, fragment", [
    ({"record_depth": 2}, "record_depth"),
    ({"nc": 0}, "nc"),
    ({"cache": {"screen_latent": {"features": 0}}}, "features"),
])
def test_invalid_ss_nirc_parameters(values, fragment):
    from renderers.methods import MethodError

    with pytest.raises(MethodError, match=fragment):
        parse_params("ss-nirc", values)
