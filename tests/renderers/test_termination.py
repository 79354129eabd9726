"""Path termination as a policy object (renderers/integrators/termination).

The policies reproduce the images the caching integrators rendered before
termination was a policy object: ``golden/termination_before.npz`` holds 16x16
renders (max_depth 6, 2 spp, 2 frames after 3 pre-training frames, seed parts
('ref', 7)) made by the code that branched on the termination string, and, for
adaptive termination, integrator renders with a fixed v1 mask on an untrained cache.
``nirc_nvc_env`` was rendered again when its visibility cache's learning-rate schedule was
repaired: the first image came from a training that stepped each parameter with a power
of Adam's debiasing factor (0.10 away); the stored one equals, to 2.4e-7, the render of
the code from before the cache's training step was frozen.

They are compared to within GOLDEN_ATOL, not bit for bit: Dr.Jit's LLVM backend
vectorises for the CPU it runs on (8 lanes with AVX2, 16 with AVX-512), which
changes the order of float sums in the caches' training and in the per-lane
reductions. Measured on an AVX2 machine against images made on another CPU, the
same code differed by at most 8.2e-5 per value (2.2e-5 relative on average); a
termination that changes (``sph_c`` doubled) differs by 0.010-0.094 at most, and
``test_a_changed_termination_is_outside_the_tolerance`` keeps that margin checked.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
from pydantic import BaseModel, Field, ValidationError

from renderers.integrators import termination
from renderers.integrators.termination import (
    POLICIES,
    TerminationPolicy,
    TerminationQuery,
    TerminationSettings,
    make_policy,
    policy_names,
    policy_params,
)
from renderers.methods import METHODS, MethodError, parse_params
from tests.support.untimed import UNTIMED

GOLDEN = Path(__file__).parent / "golden" / "termination_before.npz"
RES = 16
#: Largest difference of one value allowed between a render and its golden image
#: (module doc: 25x the cross-CPU difference measured, 5x under a planted change).
GOLDEN_ATOL = 2e-3

#: name in the golden file -> (method, parameters, scene)
CONFIGS: dict[str, tuple[str, dict[str, Any], str]] = {
    "nirc_bth": ("nirc", {"estimator": "biased", "termination": "bth"}, "cornell-box"),
    "nirc_sph": ("nirc", {"estimator": "biased", "termination": "sph"}, "cornell-box"),
    "nirc_sph_c1": ("nirc", {"estimator": "biased", "termination": "sph", "sph_c": 1.0},
                    "cornell-box"),
    "nirc_adaptive": ("nirc", {"estimator": "biased", "termination": "adaptive", "nc": [8, 2]},
                      "cornell-box"),
    "nirc_unbiased": ("nirc", {"estimator": "unbiased"}, "cornell-box"),
    "nrc_sph": ("nrc", {"termination": "sph"}, "cornell-box"),
    "nrc_adaptive": ("nrc", {"termination": "adaptive"}, "cornell-box"),
    "nrc_pt_training": ("nrc", {"self_training": False}, "cornell-box"),
    "nirc_nvc_env": ("nirc-nvc-env", {}, "sky"),
}
PRETRAIN = {"nirc_nvc_env": 2}


def _params(name: str) -> Any:
    method, params, _scene = CONFIGS[name]
    return parse_params(method, {"max_depth": 6, "pretrain_frames": PRETRAIN.get(name, 3),
                                 **params})


@pytest.fixture(scope="module")
def golden() -> dict[str, np.ndarray]:
    return dict(np.load(GOLDEN))


def _render(name: str, params: Any) -> np.ndarray:
    from renderers.scenes import load_scene

    method, _params_json, scene_name = CONFIGS[name]
    out = METHODS[method].render(load_scene(scene_name, RES), params,
                                 seed_parts=("ref", 7), spp=2, frames=2, hooks=UNTIMED)
    return np.asarray(out.accumulated)


@pytest.mark.parametrize("name", list(CONFIGS))
def test_policies_reproduce_the_images_from_before(mi, golden, name):
    np.testing.assert_allclose(_render(name, _params(name)), golden[name],
                               rtol=0, atol=GOLDEN_ATOL)


def test_a_changed_termination_is_outside_the_tolerance(mi, golden):
    """The golden comparison can fail: NRC's spread threshold doubled (the smallest
    change measured among the configurations the threshold reaches) moves some
    value by more than GOLDEN_ATOL."""
    params = _params("nrc_adaptive")
    changed = _render("nrc_adaptive", params.model_copy(update={"sph_c": 2 * params.sph_c}))
    assert np.abs(changed - golden["nrc_adaptive"]).max() > 2 * GOLDEN_ATOL


@pytest.mark.parametrize("name", ["nirc_adaptive", "nrc_adaptive"])
def test_adaptive_policy_reproduces_masked_images_from_before(mi, golden, name):
    from renderers.scenes import load_scene

    method = CONFIGS[name][0]
    scene = load_scene("cornell-box", RES)
    integrator, _trainer, cache = METHODS[method].build(scene, _params(name), 3)
    integrator.cache = cache
    integrator.set_v1_mask((np.indices((RES, RES)).sum(axis=0) % 3) != 0)
    image = np.asarray(mi.render(scene.scene, integrator=integrator, spp=3, seed=5))
    np.testing.assert_allclose(image, golden[f"{name}_mask"], rtol=0, atol=GOLDEN_ATOL)


def test_each_policy_is_declared_in_its_own_module():
    for name, cls in POLICIES.items():
        assert cls.name == name and cls.description and cls.serves
        # A module name cannot hold the hyphen of 'var-bound': its underscore stands in.
        assert cls.__module__ == f"{termination.__name__}.{name.replace('-', '_')}"


def test_methods_accept_the_policies_of_the_cache_they_have():
    assert set(policy_names("incident")) == {"bth", "sph", "adaptive"}
    assert set(policy_names("outgoing")) == {"sph", "adaptive"}
    assert set(policy_names("grid")) == {"var-bound", "mse-min", "area-spread"}
    with pytest.raises(MethodError, match="termination"):
        parse_params("nrc", {"termination": "bth"})
    with pytest.raises(MethodError, match="termination"):
        parse_params("nirc", {"termination": "magic"})


def test_policy_parameters_are_validated_by_the_policy_and_left_out_when_empty():
    dumped = parse_params("nirc", {"termination": "sph"}).model_dump(mode="json")
    assert "termination_params" not in dumped
    with pytest.raises(MethodError, match="Extra inputs"):
        parse_params("nirc", {"termination": "sph", "termination_params": {"t": 1.0}})


def test_the_nc_coupling_follows_the_policy():
    assert parse_params("nirc", {"termination": "bth"}).termination_nc() == (4, 4)
    assert parse_params("nirc", {"termination": "adaptive"}).termination_nc() == (1, 1)
    assert parse_params("nirc", {"termination": "adaptive", "nc": [8, 2]}).termination_nc() \
        == (8, 2)
    with pytest.raises(MethodError, match="one N_c"):
        parse_params("nirc", {"termination": "sph", "nc": [8, 2]})


class _Threshold(BaseModel):
    threshold: float = Field(gt=0.0)


class _ToyPolicy(TerminationPolicy):
    """Stop everywhere (weight 0) below ``threshold`` 1, else continue: a policy of the tests."""

    name = "toy"
    description = "a constant continuation weight"
    serves = frozenset({"incident"})
    Params: ClassVar[type[BaseModel]] = _Threshold

    def continuation(self, query: TerminationQuery) -> tuple[Any, Any]:
        import mitsuba as mi

        return mi.Float(0.0 if self.params.threshold < 1.0 else 1.0), query.state


@pytest.fixture
def toy(monkeypatch):
    monkeypatch.setitem(POLICIES, _ToyPolicy.name, _ToyPolicy)
    return _ToyPolicy


def test_a_registered_policy_gets_its_typed_parameters(toy):
    policy = make_policy(policy_params("toy", threshold=2.0), TerminationSettings(0.01))
    assert isinstance(policy, toy) and policy.params.threshold == 2.0
    with pytest.raises(ValidationError):
        policy_params("toy", threshold=-1.0)
    with pytest.raises(ValueError, match="unknown termination policy"):
        policy_params("none-such")


@pytest.mark.parametrize("threshold, used", [(0.5, True), (1.0, False)])
def test_the_integrator_asks_the_policy_at_each_vertex(mi, toy, threshold, used):
    """A policy that always continues leaves the cache unused; one that stops
    (weight < 1) at every usable vertex sends every path into it at the first."""
    from renderers.scenes import load_scene

    scene = load_scene("cornell-box", 8)
    params = parse_params("nirc", {"estimator": "biased", "max_depth": 6})
    integrator, _trainer, cache = METHODS["nirc"].build(scene, params, 0)
    integrator.cache = cache
    integrator.policy = make_policy(policy_params("toy", threshold=threshold),
                                    params.termination_settings())
    image, _valid, aovs = integrator.sample(scene.scene, _sampler(mi, scene, 64),
                                            _camera_rays(mi, scene, 64))
    cache_depth = np.asarray(aovs[1])
    if used:
        assert np.mean(cache_depth == 1) > 0.5
    else:
        assert cache_depth.max() == 0


def test_nrc_refuses_a_blending_policy(toy, monkeypatch):
    from renderers.integrators.nrc import refuse_blending

    monkeypatch.setattr(toy, "blends", True)
    with pytest.raises(ValueError, match="blends"):
        refuse_blending(make_policy(policy_params("toy", threshold=0.5), TerminationSettings(0.01)))


class _FirstVertex(BaseModel):
    alpha: float = Field(ge=0.0, le=1.0)


class _BlendAtTheFirstVertex(TerminationPolicy):
    """Continuation weight ``alpha`` at the first vertex, 1 after: a policy of the tests."""

    name = "blend-first"
    description = "a constant blend at the first vertex"
    serves = frozenset({"incident"})
    Params: ClassVar[type[BaseModel]] = _FirstVertex
    blends = True

    def continuation(self, query: TerminationQuery) -> tuple[Any, Any]:
        import drjit as dr
        import mitsuba as mi

        return dr.select(query.vertex.depth == 0, mi.Float(self.params.alpha),
                         mi.Float(1.0)), query.state


@pytest.mark.parametrize("alpha", [0.25, 0.5])
def test_a_continuation_weight_blends_the_cache_with_the_next_segment(mi, monkeypatch, alpha):
    """With weight alpha at v1, the image is alpha x (always continue) + (1 - alpha) x
    (always stop into the cache): L_c is weighted 1 - alpha and the path after the
    emission the continuation hits (the direct light at v2 and on) alpha. The same
    random numbers drive the three renders, so this holds per pixel."""
    from renderers.scenes import load_scene

    monkeypatch.setitem(POLICIES, _BlendAtTheFirstVertex.name, _BlendAtTheFirstVertex)
    scene = load_scene("cornell-box", RES)
    params = parse_params("nirc", {"estimator": "biased", "max_depth": 6, "nc": [2]})
    integrator, _trainer, cache = METHODS["nirc"].build(scene, params, 0)
    integrator.cache = cache

    def image(weight: float) -> np.ndarray:
        integrator.policy = make_policy(policy_params("blend-first", alpha=weight),
                                        params.termination_settings())
        film = np.asarray(mi.render(scene.scene, integrator=integrator, spp=4, seed=1),
                          dtype=np.float64)
        return film[..., :3]    # the radiance (the AOVs count cache vertices)

    stop, go, blend = image(0.0), image(1.0), image(alpha)
    assert np.abs(go - stop).max() > 1e-2     # the cache and the path differ here
    np.testing.assert_allclose(blend, alpha * go + (1 - alpha) * stop, rtol=1e-4, atol=1e-6)


def _sampler(mi, scene, lanes):
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(0, lanes)
    return sampler


def _camera_rays(mi, scene, lanes):
    import drjit as dr

    sensor = scene.scene.sensors()[0]
    u = dr.arange(mi.Float, lanes) / lanes
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(u, 0.5), mi.Point2f(0.5, 0.5))
    return ray


class _PositionsCache:
    """A cache whose 'statistics' at a surface point are the point itself."""

    def statistics(self, si: Any, active: Any) -> Any:
        import drjit as dr
        import mitsuba as mi

        return dr.select(active & si.is_valid(), si.p, mi.Point3f(0.0))


class _Recorder(TerminationPolicy):
    """Records the statistics the cache gives at each vertex asked; always continues."""

    name = "recorder"
    description = "records what the cache says at the vertex"
    serves = frozenset({"incident"})
    log: ClassVar[list[Any]] = []

    def continuation(self, query: TerminationQuery) -> tuple[Any, Any]:
        import drjit as dr
        import mitsuba as mi

        here = query.statistics()
        dr.eval(here)
        self.log.append(np.asarray(here))
        return mi.Float(1.0), query.state


def test_a_policy_reads_the_cache_at_its_vertex(mi, monkeypatch):
    """The statistics a policy reads at the first vertex are the cache's at that vertex
    (the camera rays' first hits), and at the second vertex those of other points: the
    rule depends on the path's prefix only (no look-ahead along its continuation)."""
    import drjit as dr

    from renderers.scenes import load_scene

    monkeypatch.setitem(POLICIES, _Recorder.name, _Recorder)
    monkeypatch.setattr(_Recorder, "log", [])
    scene = load_scene("cornell-box", 8)
    params = parse_params("nirc", {"estimator": "biased", "max_depth": 3})
    integrator, _trainer, cache = METHODS["nirc"].build(scene, params, 0)
    integrator.cache = _PositionsCache()
    integrator.policy = make_policy(policy_params("recorder"), params.termination_settings())
    rays = _camera_rays(mi, scene, 256)
    first = scene.scene.ray_intersect(rays)
    dr.set_flag(dr.JitFlag.SymbolicLoops, False)   # each vertex's arrays are concrete
    try:
        integrator.sample(scene.scene, _sampler(mi, scene, 256), rays)
    finally:
        dr.set_flag(dr.JitFlag.SymbolicLoops, True)
    here_0, here_1 = _Recorder.log[:2]
    hit = np.asarray(first.is_valid())
    assert hit.mean() > 0.5
    np.testing.assert_allclose(here_0[:, hit], np.asarray(first.p)[:, hit], atol=1e-4)
    moved = np.all(here_1 != 0, axis=0) & hit
    assert moved.any() and not np.allclose(here_1[:, moved], here_0[:, moved], atol=1e-3)


class _CountVertices(TerminationPolicy):
    """Counts the vertices it was asked at in the path state; stops at the second."""

    name = "count"
    description = "stop at the second vertex, counted in the path state"
    serves = frozenset({"incident"})

    def continuation(self, query: TerminationQuery) -> tuple[Any, Any]:
        import drjit as dr

        state = query.state
        state.termination_value = dr.select(query.usable, state.termination_value + 1.0,
                                            state.termination_value)
        return dr.select(state.termination_value >= 2.0, 0.0, 1.0), state


def test_a_policy_carries_its_own_value_along_the_path(mi, monkeypatch):
    from renderers.scenes import load_scene

    monkeypatch.setitem(POLICIES, _CountVertices.name, _CountVertices)
    scene = load_scene("cornell-box", 8)
    params = parse_params("nirc", {"estimator": "biased", "max_depth": 6})
    integrator, _trainer, cache = METHODS["nirc"].build(scene, params, 0)
    integrator.cache = cache
    integrator.policy = make_policy(policy_params("count"), params.termination_settings())
    _image, _valid, aovs = integrator.sample(scene.scene, _sampler(mi, scene, 256),
                                             _camera_rays(mi, scene, 256))
    cache_depth = np.asarray(aovs[1])
    assert set(np.unique(cache_depth)) <= {0.0, 2.0} and np.mean(cache_depth == 2) > 0.5
