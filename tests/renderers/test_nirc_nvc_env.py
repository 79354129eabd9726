"""`nirc-nvc-env`: NIRC for indirect light + nvc-env for the environment's direct light
(renderers.integrators.nirc_nvc_env, docs/estimators.md "nirc-nvc-env").

Statistical, on `sky` (lit by its environment map only) at 16x16 against
Mitsuba's ``path`` with unbounded paths (the NIRC oracle's nested paths cannot
know how many segments a bounded render has left), per-pixel Šidák z-test and
aggregate test on Y:

* both estimators unbiased, both caches trained 4 frames: agrees;
* both unbiased with zero caches (everything from the residuals): agrees;
* both biased with perfect caches (NIRC: the path-traced oracle of L_ind with
  SPH termination; env: one exact shadow ray): agrees — the two caches'
  quantities add up to the light with nothing counted twice or left out;
* with a constant environment and an area light, the biased run with perfect
  caches agrees too (only the environment's NEE is replaced);
* planted, each rejected: that run with the core's own environment NEE kept
  as well (I_env counted twice), and the `sky` run with a zero visibility
  cache (I_env left out).
"""

from __future__ import annotations

import pytest

from metrics.statistics import agreement_test
from tests.renderers.lighting import ENV_AND_SPHERE, ShadowRayOracle, luminance_moments
from tests.support.moments import render_moments

RES = 16
SPP = 1024
TRAIN_FRAMES = 4


@pytest.fixture(scope="module")
def sky(mi):
    from renderers.scenes import load_scene

    return load_scene("sky", RES)


@pytest.fixture(scope="module")
def reference(mi, sky):
    return luminance_moments(render_moments(sky.scene, {"type": "path", "max_depth": -1},
                                            SPP, seed=1001))


def _integrator(scene, caches=None, **params):
    """The method's integrator with both caches trained ``TRAIN_FRAMES`` frames as its
    frame loop trains them, or with ``caches`` = (NIRC cache, visibility cache) doubles."""
    from renderers.methods.budget import frame_training_budget
    from renderers.methods.cached import train_once
    from renderers.methods.nirc_nvc_env import NIRCEnvParams, build
    from renderers.methods.nvc_env import train_frame
    from renderers.timing import StageTimer

    parsed = NIRCEnvParams(max_depth=-1, **params)
    integrator, trainer, cache, visibility = build(scene, parsed, seed=0)
    if caches is not None:
        integrator.cache = caches[0]
        integrator.configure_env(parsed.env(), caches[1])
        return integrator
    integrator.cache = trainer.cache = cache
    budget = frame_training_budget(RES * RES, parsed, cache.config)
    for frame in range(TRAIN_FRAMES):
        train_once(cache, trainer, scene, budget, frame, StageTimer())
        train_frame(scene, visibility, parsed.env(), frame, StageTimer())
    return integrator


def _agreement(sky, integrator, reference):
    test = luminance_moments(render_moments(sky.scene, integrator, SPP, seed=1))
    result = agreement_test(*test, *reference, alpha=0.01)
    print(result.summary())
    return result


def _oracles(sky, env_zero=False):
    from tests.support.oracle import OracleCache

    return OracleCache(sky.scene), ShadowRayOracle(sky.scene, zero=env_zero)


BIASED = {"estimator": "biased", "termination": "sph", "nc": [2], "env_estimator": "biased",
          "env_nc": 2}


@pytest.mark.slow
def test_unbiased_with_trained_caches_matches_path(mi, sky, reference):
    integrator = _integrator(sky, estimator="unbiased", nc=[2, 1], env_nc=2)
    result = _agreement(sky, integrator, reference)
    assert result.passed, result.summary()
    # (At 1024 spp the buffer would pass cached.MAX_QUERY_SLOTS: the queries ran in the
    # loop.) At 4 spp both channels are deferred: NIRC's 2 x (2 + 1) slots and the
    # environment's 3 per vertex.
    mi.render(sky.scene, integrator=integrator, spp=4, seed=5)
    count = integrator.query_counts[-1]
    assert count is not None and count.slots_per_lane >= 6 + 3 and count.queries > 0


@pytest.mark.slow
def test_unbiased_with_zero_caches_matches_path(mi, sky, reference):
    from tests.support.oracle import ZeroCache

    integrator = _integrator(sky, (ZeroCache(), ShadowRayOracle(sky.scene, zero=True)),
                             estimator="unbiased", nc=[1], env_nc=1)
    result = _agreement(sky, integrator, reference)
    assert result.passed, result.summary()


@pytest.mark.slow
def test_biased_with_perfect_caches_matches_path(mi, sky, reference):
    result = _agreement(sky, _integrator(sky, _oracles(sky), **BIASED), reference)
    assert result.passed, result.summary()


@pytest.mark.slow
@pytest.mark.parametrize("core_env_nee", [False, True], ids=["replaced", "kept-too"])
def test_with_another_emitter_only_the_env_nee_is_replaced(mi, core_env_nee):
    """A constant environment and a spherical area light (lighting.ENV_AND_SPHERE): with
    perfect caches the combination agrees with `path`; keeping the core's environment
    NEE as well (I_env counted twice) is rejected. (On `sky` the environment is the only
    emitter, so the core does no NEE at all.)"""
    from types import SimpleNamespace

    from renderers.integrators.lights import UniformLightSampler
    from tests.support.oracle import OracleCache

    scene = mi.load_string(ENV_AND_SPHERE.format(res=RES))
    integrator = _integrator(SimpleNamespace(scene=scene),
                             (OracleCache(scene), ShadowRayOracle(scene)), **BIASED)
    if core_env_nee:
        integrator.light_sampler_type = UniformLightSampler
    reference = luminance_moments(render_moments(scene, {"type": "path", "max_depth": -1},
                                                 SPP, seed=1001))
    result = _agreement(SimpleNamespace(scene=scene), integrator, reference)
    assert result.passed != core_env_nee, result.summary()


@pytest.mark.slow
def test_leaving_the_env_nee_out_is_rejected(mi, sky, reference):
    integrator = _integrator(sky, _oracles(sky, env_zero=True), **BIASED)
    assert not _agreement(sky, integrator, reference).passed


def test_a_run_stores_both_caches_resolved_configuration(mi, sky):
    """Through the method's frame loop: each cache under the parameter that overrides it,
    with its whole network and its training per frame."""
    from renderers.methods import METHODS, parse_params

    params = parse_params("nirc-nvc-env", {"env_camera_points": 256,
                                           "cache": {"batch_size": 256},
                                           "env_cache": {"batch_size": 256}})
    output = METHODS["nirc-nvc-env"].render(sky, params, seed_parts=("caches",), spp=1,
                                            frames=1)
    caches = output.method_stats["caches"]
    assert set(caches) == {"cache", "env_cache"}
    assert caches["cache"]["config"]["mlp"]["hidden_layers"] == 4
    assert caches["cache"]["per_frame"]["steps"] == 4
    assert caches["env_cache"]["config"]["output"]["activation"] == "sigmoid"
    assert caches["env_cache"]["per_frame"] == {"points": 256, "steps": 1, "batch_size": 256,
                                                "records": 256}
