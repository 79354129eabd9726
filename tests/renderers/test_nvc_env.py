"""`nvc-env`: direct environment light through a neural visibility cache
(renderers.integrators.nvc_env, docs/estimators.md "nvc-env").

Fast: registration, ``applies_to`` (no environment map: skipped, saying so),
training targets are shadow-ray outcomes. Statistical (slow), on `sky` (lit
only by its environment map) against Mitsuba's ``path`` with the per-pixel
Šidák z-test and the aggregate test (Y channel), as test_nvc_lights.py:

* unbiased with a trained cache, direct light only (max_depth 2) and full GI;
  with a zero cache and a shadow-ray oracle as the cache (direct);
* the planted bias: dropping the residual of a briefly trained cache
  (``estimator='biased'``) is rejected;
* biased with the oracle (exact visibility) agrees with ``path``; biased with a
  zero cache has the known expectation "PT without the environment's NEE"
  (the PT core with :class:`WithoutEnvironmentNEE` and nothing else).

``target='radiance'`` (the cache predicts L_env V, RGB: NIRC predicting the
same direct light, Fig. 11) passes the same zero, oracle and trained-cache
tests; its radiance fed through the visibility factor (L_env twice) is rejected.

The two oracle tests also check the MIS bookkeeping: the env NEE term carries
w_L, the core's BSDF-sampled environment hits keep w_bsdf = 1 - w_L; counting
either fully would add light and fail. With a constant environment and an area
light (lighting.ENV_AND_SPHERE) only the environment's NEE is replaced: the
unbiased estimator with a zero cache and the biased one with the oracle agree
with `path`, and keeping the core's env NEE as well (counted twice) is rejected.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from metrics.statistics import agreement_test
from tests.renderers.lighting import ENV_AND_SPHERE, ShadowRayOracle, luminance_moments
from tests.support.moments import render_moments

RES = 16
SPP = 1024
NC = 2          # small: the kernel's compile time grows with N_c
TRAIN_FRAMES = 4


@pytest.fixture(scope="module")
def sky(mi):
    from renderers.scenes import load_scene

    return load_scene("sky", RES)


def _integrator(scene, cache=None, frames=TRAIN_FRAMES, **params):
    """nvc-env's integrator; with ``cache`` (a test double) instead of the trained one."""
    from renderers.methods.nvc_env import NVCEnvParams, build, train_frame
    from renderers.timing import StageTimer

    parsed = NVCEnvParams(nc=NC, **params)
    integrator, trained = build(scene, parsed, seed=0)
    if cache is None:
        for frame in range(frames):
            train_frame(scene, trained, parsed, frame, StageTimer())
    else:
        integrator.configure(parsed, cache)
    return integrator


def _agreement(scene, integrator, max_depth, reference=None, seed=1):
    test = luminance_moments(render_moments(scene, integrator, SPP, seed=seed))
    reference = reference or {"type": "path", "max_depth": max_depth}
    ref = luminance_moments(render_moments(scene, reference, SPP, seed=seed + 1000))
    result = agreement_test(*test, *ref, alpha=0.01)
    print(result.summary())
    return result


# ---------------------------------------------------------------------------
# Registration, applicability, training data (fast)
# ---------------------------------------------------------------------------

def test_registered_with_the_papers_defaults():
    from renderers.methods import METHODS, MethodError, parse_params

    params = parse_params("nvc-env", {"max_depth": 2})
    assert (params.estimator, params.nc, params.camera_points) == ("unbiased", 7, 4096)
    with pytest.raises(MethodError, match="estimator"):
        parse_params("nvc-env", {"estimator": "control-variate"})
    assert METHODS["nvc-env"].applies_to(SimpleNamespace(has_envmap=True, shape_count=3)) == \
        (True, "")


def test_applies_to_cornell_box_gives_the_reason(mi):
    from renderers.methods import METHODS
    from renderers.scenes import load_scene

    features = load_scene("cornell-box", RES).features
    assert METHODS["nvc-env"].applies_to(features) == (False, "no environment map")


def test_training_targets_are_shadow_ray_outcomes(mi, sky):
    from renderers.integrators.nvc_env import visibility_records

    records = visibility_records(sky.scene, 512, seed=1)
    target, valid = records.target[0].numpy(), records.valid.numpy()
    assert len(records) == 1024 and set(np.unique(target)) <= {0.0, 1.0}
    assert 0.5 < valid[:512].mean() < 0.95   # the camera sees the courtyard and the sky
    assert not target[~valid].any()
    # The courtyard hides much of the sky (and the sun) from much of it.
    assert 0.1 < target[valid].mean() < 0.9


# ---------------------------------------------------------------------------
# Agreement with Mitsuba's path; planted bias; oracles (slow)
# ---------------------------------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("max_depth", [2, -1], ids=["direct", "global"])
def test_unbiased_with_a_trained_cache_matches_path(mi, sky, max_depth):
    integrator = _integrator(sky, max_depth=max_depth)
    result = _agreement(sky.scene, integrator, max_depth)
    assert result.passed, result.summary()
    # Direct light: the queries were deferred (not evaluated in the loop), some used.
    # (Full GI at 1024 spp: the longest of 262144 paths needs so many vertex slots
    # that the buffer would pass cached.MAX_QUERY_SLOTS; that frame queries inline.)
    count = integrator.query_counts[-1]
    if max_depth == 2:
        assert count is not None and 0 < count.queries < count.lanes * count.slots_per_lane


@pytest.mark.slow
@pytest.mark.parametrize("target", ["visibility", "radiance"])
@pytest.mark.parametrize("zero", [True, False], ids=["zero", "oracle"])
def test_unbiased_with_any_cache_matches_path(mi, sky, zero, target):
    cache = ShadowRayOracle(sky.scene, zero=zero, radiance=target == "radiance")
    result = _agreement(sky.scene, _integrator(sky, cache, max_depth=2, target=target), 2)
    assert result.passed, result.summary()


@pytest.mark.slow
def test_unbiased_with_a_trained_radiance_cache_matches_path(mi, sky):
    """The Fig. 11 variant: NIRC's network predicting L_env V, trained 4 frames."""
    integrator = _integrator(sky, max_depth=2, target="radiance")
    result = _agreement(sky.scene, integrator, 2)
    assert result.passed, result.summary()


@pytest.mark.slow
def test_dropping_the_residual_is_rejected(mi, sky):
    """Power: the cache level alone of a cache trained 2 frames is visibly biased."""
    integrator = _integrator(sky, frames=2, max_depth=2, estimator="biased")
    result = _agreement(sky.scene, integrator, 2)
    assert not result.passed, result.summary()


@pytest.mark.slow
@pytest.mark.parametrize("target", ["visibility", "radiance"])
def test_biased_with_the_oracle_matches_path(mi, sky, target):
    oracle = ShadowRayOracle(sky.scene, radiance=target == "radiance")
    integrator = _integrator(sky, oracle, max_depth=2, estimator="biased", target=target)
    result = _agreement(sky.scene, integrator, 2)
    assert result.passed, result.summary()


@pytest.mark.slow
def test_radiance_values_with_the_visibility_factor_are_rejected(mi, sky):
    """Power of the radiance target's check: the radiance oracle's L_env V weighted by
    the visibility factor g = L_env f cos w_L / p_env (L_env counted twice)."""
    oracle = ShadowRayOracle(sky.scene, radiance=True)
    integrator = _integrator(sky, oracle, max_depth=2, estimator="biased")
    assert not _agreement(sky.scene, integrator, 2).passed


@pytest.mark.slow
def test_biased_with_a_zero_cache_drops_exactly_the_env_nee(mi, sky):
    from renderers.integrators.nvc_env import WithoutEnvironmentNEE
    from tests.renderers.lighting import pt_integrator

    integrator = _integrator(sky, ShadowRayOracle(sky.scene, zero=True), max_depth=2,
                             estimator="biased")
    without_env_nee = pt_integrator(mi, WithoutEnvironmentNEE, max_depth=2)
    result = _agreement(sky.scene, integrator, 2, reference=without_env_nee)
    assert result.passed, result.summary()
    # ... and it is far from path: the env NEE is most of the direct light.
    assert not _agreement(sky.scene, integrator, 2).passed


@pytest.mark.slow
@pytest.mark.parametrize("estimator", ["unbiased", "biased"])
def test_with_another_emitter_only_the_env_nee_is_replaced(mi, estimator):
    """A constant environment and a spherical area light: the core's NEE keeps the area
    light (uniform selection, env-selected samples dropped) and both MIS weights. The
    unbiased estimator with a zero cache (all of I_env from the residual) and the
    biased one with the oracle agree with `path`."""
    scene = mi.load_string(ENV_AND_SPHERE.format(res=RES))
    cache = ShadowRayOracle(scene, zero=estimator == "unbiased")
    integrator = _integrator(SimpleNamespace(scene=scene), cache, max_depth=2,
                             estimator=estimator)
    assert _agreement(scene, integrator, 2).passed


@pytest.mark.slow
def test_counting_the_env_nee_twice_is_rejected(mi):
    """Power of the check above: the same biased oracle with the core's own selector
    (its env NEE kept as well) adds the environment's light twice."""
    from renderers.integrators.lights import UniformLightSampler

    scene = mi.load_string(ENV_AND_SPHERE.format(res=RES))
    integrator = _integrator(SimpleNamespace(scene=scene), ShadowRayOracle(scene),
                             max_depth=2, estimator="biased")
    integrator.light_sampler_type = UniformLightSampler
    assert not _agreement(scene, integrator, 2).passed
