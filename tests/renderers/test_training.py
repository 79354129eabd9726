"""Training paths estimate what the render paths need (docs/training.md).

Most tests use a *furnace*: the camera inside a closed box whose inner
surface emits L_e and reflects diffusely with albedo rho. Every vertex then sees the
same radiance, so all expectations are closed-form sums of a geometric series.
With a path bounded to D segments (the camera segment included):

- a pixel gets L_e * sum_{k<D} rho^k (emission of x_0 ... x_{D-1});
  unbounded (D = -1): L_e / (1 - rho);
- a NIRC record at x_j (departure, target = radiance reflected at x_{j+1}
  toward x_j without x_{j+1}'s emission, NIRC paper Eq. 8-9) gets
  L_e * sum_{m=1}^{D-j-2} rho^m; unbounded rho L_e / (1 - rho);
- an NRC record at x_j (arrival, target = radiance reflected at x_j) gets
  L_e * sum_{m=1}^{D-j-1} rho^m, divided by the demodulation factor rho.

Expected values are checked with confidence intervals (level 0.999) or the
statistical agreement test; ~65k paths each.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from metrics.statistics import agreement_test, mean_confidence_interval
from renderers.methods import MethodError, parse_params

RHO = 0.5
LE = 1.0
N_PATHS = 1 << 16
LEVEL = 0.999
RECORD_DEPTH = 3


# ---- Scenes and closed-form expectations ----

def _furnace_dict(mi, rho=RHO, le=LE, res=16, bsdf=None):
    """The camera inside a closed cube of six inward-facing rectangles that all
    emit ``le`` and share one BSDF (diffuse ``rho`` unless given). A cube, not
    a sphere seen from inside: Mitsuba's sphere NEE from an interior point was
    measured ~0.07 % high per bounce, which the tests here would detect."""
    T = mi.ScalarTransform4f
    faces = {"bottom": T().translate([0, 0, -1]),
             "top": T().translate([0, 0, 1]) @ T().rotate([1, 0, 0], 180),
             "left": T().translate([-1, 0, 0]) @ T().rotate([0, 1, 0], 90),
             "right": T().translate([1, 0, 0]) @ T().rotate([0, 1, 0], -90),
             "front": T().translate([0, -1, 0]) @ T().rotate([1, 0, 0], -90),
             "back": T().translate([0, 1, 0]) @ T().rotate([1, 0, 0], 90)}
    scene = {
        "type": "scene",
        "sensor": {
            "type": "perspective", "fov": 100,
            "to_world": T().look_at(origin=[0.1, 0.2, 0.05], target=[1.0, 0.3, 0.2],
                                    up=[0, 0, 1]),
            "film": {"type": "hdrfilm", "width": res, "height": res,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent"},
        },
        "material": bsdf or {"type": "diffuse",
                             "reflectance": {"type": "rgb", "value": [rho] * 3}},
    }
    for name, to_world in faces.items():
        scene[name] = {"type": "rectangle", "to_world": to_world,
                       "bsdf": {"type": "ref", "id": "material"},
                       "emitter": {"type": "area",
                                   "radiance": {"type": "rgb", "value": [le] * 3}}}
    return scene


def _furnace(mi, **kwargs):
    return mi.load_dict(_furnace_dict(mi, **kwargs))


def _series(first: int, last: int, rho: float = RHO) -> float:
    """sum_{m=first}^{last} rho^m; ``last`` None = infinity."""
    if last is None:
        return rho**first / (1.0 - rho)
    return sum(rho**m for m in range(first, last + 1))


def pixel_value(max_depth: int) -> float:
    return LE * _series(0, None if max_depth == -1 else max_depth - 1)


def nirc_target(max_depth: int, j: int) -> float:
    return LE * _series(1, None if max_depth == -1 else max_depth - j - 2)


def nrc_reflected(max_depth: int, j: int) -> float:
    return LE * _series(1, None if max_depth == -1 else max_depth - j - 1)


def _loaded(scene, res=16):
    """What the method builders need of a loaded scene."""
    return SimpleNamespace(scene=scene, resolution=(res, res))


def _trainer(mi, scene, method, **params):
    from renderers.methods import nirc, nrc

    module = {"nirc": nirc, "nrc": nrc}[method]
    integrator, trainer, cache = module.build(_loaded(scene), parse_params(method, params), seed=3)
    return integrator, trainer, cache


def _records(trainer, scene, seed=11, n_paths=N_PATHS):
    """(valid (n, D) bool, target (n, D, 3), full record dict as numpy)."""
    records = trainer.trace_records(scene, n_paths, seed)
    # Record r = path * RECORD_DEPTH + j; 3-vectors come channel-major (3, n * D).
    out = {name: np.asarray(value) for name, value in records.items()}
    out = {name: (value.T.reshape(n_paths, RECORD_DEPTH, 3) if value.ndim == 2
                  else value.reshape(n_paths, RECORD_DEPTH)) for name, value in out.items()}
    return out["valid"], out["target"], out


def _assert_mean(values: np.ndarray, expected: float, what: str) -> None:
    mean, lo, hi = mean_confidence_interval(values, LEVEL)
    assert lo <= expected <= hi, (f"{what}: mean {mean:.5f}, {LEVEL:.1%} CI [{lo:.5f}, {hi:.5f}] "
                                  f"does not contain {expected:.5f}")


class ConstantCache:
    """A cache stub whose (demodulated) output is ``value`` everywhere."""

    def __init__(self, value: float) -> None:
        self.value = value
        self.queries = 0

    def surface_features(self, **inputs):
        return []

    def query(self, surface, direction=None):
        import mitsuba as mi

        self.queries += 1
        return mi.Color3f(self.value)


# ---- Defaults: one depth for renders, references and training ----

def test_default_depth_is_unbounded_everywhere():
    from jobs.protocol.job import RenderJob
    from jobs.protocol.spec import RenderSpec, SweepSpec
    from renderers.methods.pt import PTParams
    from renderers.reference import ReferenceSettings

    assert PTParams().max_depth == -1
    assert parse_params("nirc", {}).max_depth == -1
    assert parse_params("nrc", {}).max_depth == -1
    assert ReferenceSettings().max_depth == -1
    assert RenderJob.parse(RenderSpec(scene="door")).max_depth == -1
    sweep = SweepSpec(scene="door", nc=[1])
    assert sweep.max_depth == -1
    assert RenderJob.parse(sweep.base_render_spec()).max_depth == -1
    with pytest.raises(ValueError, match="max_depth"):
        SweepSpec(scene="door", nc=[1], max_depth=0)


@pytest.mark.parametrize("method", ["nirc", "nrc"])
@pytest.mark.parametrize("params", [{}, {"max_depth": 5}, {"max_depth": 5, "rr_depth": 2,
                                                            "rr_mode": "throughput"}])
def test_training_paths_share_the_render_paths_core(mi, method, params):
    integrator, trainer, _ = _trainer(mi, _furnace(mi, res=4), method, **params)
    for name in ("max_depth", "rr_depth", "rr_mode", "rr_survival"):
        assert getattr(trainer, name) == getattr(integrator, name), name


def test_train_max_depth_is_gone_with_a_clear_message():
    with pytest.raises(MethodError, match="train_max_depth was removed.*max_depth"):
        parse_params("nirc", {"train_max_depth": 8})


# ---- (a) The converged PT image of the furnace ----

@pytest.mark.parametrize("kind, max_depth", [
    ("pt", None), ("pt", 3), ("reference-path", None), ("reference-pt", None)])
def test_furnace_pixels_equal_the_series(mi, kind, max_depth):
    """Every pixel converges to L_e sum_{k<D} rho^k (L_e / (1 - rho) unbounded).

    ``None`` = the default depth, which must be the unbounded one: with the
    old default (8) the pixels sit 0.4 % low, ~6 standard errors of the
    block means at this sample count. The Mitsuba reference (throughput-based
    roulette) and our core (fixed survival 0.9) have the same expectation.
    """
    from renderers.methods.pt import PTParams, path_integrator
    from renderers.reference import ReferenceSettings, reference_integrator
    from tests.support.moments import render_moments

    scene = _furnace(mi)
    if kind == "pt":
        params = PTParams() if max_depth is None else PTParams(max_depth=max_depth)
        integrator, depth = path_integrator(params), params.max_depth
    else:
        settings = ReferenceSettings(integrator=kind.split("-")[1])
        integrator, depth = reference_integrator(settings), settings.max_depth
    # 16 x 16 pixels x 256 spp: 65k paths. Mitsuba's throughput roulette has
    # heavy-tailed samples (weights up to 1/q with small q) whose per-pixel
    # variance 256 samples underestimate now and then (measured: one pixel at
    # z = -4.9 for seed 5, fine at 1024 spp): 4x the samples there.
    spp = 1024 if kind == "reference-path" else 256
    mean, var = render_moments(scene, integrator, spp, seed=5)
    # Luminance Y of the XYZ moments: a grey value v has Y = v.
    mean_y, var_y = mean[..., 1:2], var[..., 1:2]
    expected = pixel_value(-1 if max_depth is None else max_depth)
    result = agreement_test(mean_y, var_y, np.full_like(mean_y, expected),
                            np.zeros_like(var_y), alpha=0.001)
    assert result.passed, f"depth {depth}: expected {expected:.5f}, got mean " \
                          f"{mean_y.mean():.5f}: {result.summary()}"


# ---- (b) NIRC training targets (departure records) ----

@pytest.mark.parametrize("max_depth", [None, 4])
def test_nirc_furnace_targets(mi, max_depth):
    """Mean valid target at record j = rho L_e / (1 - rho), or the truncated sum
    L_e sum_{m=1}^{D-j-2} rho^m when the training path stops at D like a render
    path. Records that cannot depart (j >= D - 1) are invalid."""
    scene = _furnace(mi)
    params = {} if max_depth is None else {"max_depth": max_depth}
    _, trainer, _ = _trainer(mi, scene, "nirc", **params)
    valid, target, _ = _records(trainer, scene)
    depth = -1 if max_depth is None else max_depth
    for j in range(RECORD_DEPTH):
        departs = depth == -1 or j < depth - 1
        if not departs:
            assert not valid[:, j].any(), f"record {j} cannot depart at max_depth {depth}"
            continue
        # A closed box: every path reaches x_{j+1} (roulette starts at depth 5).
        assert valid[:, j].mean() > 0.999, f"record {j}: {valid[:, j].mean():.4f} valid"
        _assert_mean(target[valid[:, j], j].mean(axis=1), nirc_target(depth, j),
                     f"max_depth {depth}, record {j}")


# ---- (c) NRC training targets (arrival records, demodulated) ----

@pytest.mark.parametrize("max_depth", [None, 4])
def test_nrc_furnace_targets(mi, max_depth):
    """Arrival records at x_j: target * rho = L_e sum_{m=1}^{D-j-1} rho^m
    (rho L_e / (1 - rho) unbounded); the stored target is divided by the
    demodulation factor rho, so its mean is that over rho."""
    scene = _furnace(mi)
    params = {"self_training": False}
    if max_depth is not None:
        params["max_depth"] = max_depth
    _, trainer, _ = _trainer(mi, scene, "nrc", **params)
    valid, target, records = _records(trainer, scene)
    albedo = records["albedo"]
    depth = -1 if max_depth is None else max_depth
    for j in range(RECORD_DEPTH):
        assert valid[:, j].mean() > 0.999, f"record {j}: {valid[:, j].mean():.4f} valid"
        np.testing.assert_allclose(albedo[valid[:, j], j], RHO, rtol=1e-6)
        _assert_mean(target[valid[:, j], j].mean(axis=1), nrc_reflected(depth, j) / RHO,
                     f"max_depth {depth}, record {j}")


# ---- NIRC targets on a non-furnace scene: one shading point of the Cornell box ----

def _cornell_pinhole(mi):
    """The Cornell box seen through a 1x1 film with a tiny field of view: every
    camera ray hits (nearly) the same point x_0 of the back wall."""
    scene = mi.cornell_box()
    scene["sensor"]["fov"] = 0.01
    scene["sensor"]["to_world"] = mi.ScalarTransform4f().look_at(
        origin=[0, 0, 3.9], target=[0.3, 0.4, -1], up=[0, 1, 0])
    scene["sensor"]["film"].update(width=1, height=1, rfilter={"type": "box"})
    scene["sensor"]["sampler"] = {"type": "independent"}
    return mi.load_dict(scene)


def _lane_radiance(mi, scene, integrator, n, seed):
    """n one-sample estimates of the radiance along the camera rays (RGB, (n, 3))."""
    import drjit as dr

    sensor = scene.sensors()[0]
    sampler = sensor.sampler().clone()
    sampler.seed(seed, n)
    ray, _ = sensor.sample_ray(time=0.0, sample1=sampler.next_1d(),
                               sample2=sampler.next_2d(), sample3=sampler.next_2d())
    L, _, _ = integrator.sample(scene, sampler, ray, None, True)
    L = mi.Color3f(L)
    dr.eval(L)
    return np.asarray(L).T


@pytest.mark.parametrize("max_depth", [None, 4])
def test_nirc_primary_target_is_the_indirect_light_of_mitsubas_path(mi, max_depth):
    """At a fixed diffuse point x_0, albedo * E[target_0] (directions cosine
    sampled) is the indirect light reflected at x_0: Mitsuba's ``path`` at
    depth D minus ``path`` at depth 2 (emission + direct light). Independent
    code, and a scene where paths longer than 4 segments carry ~1/3 of the indirect
    light, so a training path longer than the render path shows."""
    scene = _cornell_pinhole(mi)
    depth = -1 if max_depth is None else max_depth
    params = {} if max_depth is None else {"max_depth": max_depth}
    _, trainer, _ = _trainer(mi, scene, "nirc", **params)
    valid, target, records = _records(trainer, scene, n_paths=N_PATHS)
    albedo = records["albedo"][:, 0]
    assert valid[:, 0].mean() > 0.99
    # x_0 is on one diffuse wall: one albedo.
    seen = albedo[valid[:, 0]]
    np.testing.assert_allclose(seen, np.broadcast_to(seen[0], seen.shape), rtol=1e-5)
    indirect = (albedo * target[:, 0])[valid[:, 0]]

    full = _lane_radiance(mi, scene, mi.load_dict({"type": "path", "max_depth": depth}),
                          4 * N_PATHS, seed=21)
    direct = _lane_radiance(mi, scene, mi.load_dict({"type": "path", "max_depth": 2}),
                            N_PATHS, seed=22)
    # Welch-style interval on (mean indirect record) - (mean full - mean direct), per channel.
    for c in range(3):
        diff = indirect[:, c].mean() - (full[:, c].mean() - direct[:, c].mean())
        stderr = np.sqrt(indirect[:, c].var(ddof=1) / len(indirect)
                         + full[:, c].var(ddof=1) / len(full)
                         + direct[:, c].var(ddof=1) / len(direct))
        assert abs(diff) < 3.3 * stderr, (
            f"max_depth {depth}, channel {c}: records {indirect[:, c].mean():.5f}, "
            f"path {full[:, c].mean() - direct[:, c].mean():.5f} (diff {diff:.5f}, "
            f"stderr {stderr:.5f})")


# ---- NRC self-training: invalidation and the self-trained target ----

def test_nrc_self_training_invalidates_records_at_the_terminal_vertex(mi):
    """With a tiny spread constant every self-training path terminates into the
    cache at its second vertex x_1, except every ``unbiased_every``-th path,
    which never does. Record 1 (the cache's own output) and record 2 (never
    reached) of terminated paths are invalid; all records of the unbiased
    paths are valid. With a constant demodulated cache output C the valid
    targets have the expectations

        terminated paths, record 0:  (rho L_e + rho * C * rho) / rho = L_e + rho C
        unbiased paths, every record: L_e / (1 - rho)   (plain PT)
    """
    every, value = 4, 3.0
    scene = _furnace(mi)
    _, trainer, _ = _trainer(mi, scene, "nrc", sph_c=1e-9, unbiased_every=every)
    trainer.cache = ConstantCache(value)
    valid, target, _ = _records(trainer, scene)
    assert trainer.cache.queries > 0

    unbiased = np.arange(N_PATHS) % every == 0
    expected_valid = np.zeros_like(valid)
    expected_valid[unbiased] = True
    expected_valid[~unbiased, 0] = True
    mismatch = valid != expected_valid
    assert mismatch.mean() < 1e-3, (
        f"{mismatch.sum()} records differ from the expected pattern; per record "
        f"(terminated paths) valid fractions {valid[~unbiased].mean(axis=0)}, "
        f"(unbiased paths) {valid[unbiased].mean(axis=0)}")

    terminated = valid[:, 0] & ~unbiased
    _assert_mean(target[terminated, 0].mean(axis=1), LE + RHO * value,
                 "terminated paths, record 0")
    for j in range(RECORD_DEPTH):
        ok = valid[:, j] & unbiased
        _assert_mean(target[ok, j].mean(axis=1), nrc_reflected(-1, j) / RHO,
                     f"unbiased paths, record {j}")


# ---- Albedo demodulation ----

def test_demodulation_factor_is_floored(mi):
    import mitsuba as mi_

    from renderers.integrators.cached import MIN_DEMODULATION, demodulation

    factor = demodulation({"albedo": mi_.Color3f(0.0, 0.2, 0.5),
                           "albedo_spec": mi_.Color3f(0.0, 0.3, 1.0)})
    np.testing.assert_allclose(np.asarray(factor).ravel(), [MIN_DEMODULATION, 0.5, 1.5],
                               rtol=1e-6)


def test_nrc_targets_times_demodulation_are_the_reflected_radiance(mi):
    """A plastic furnace (diffuse 0.3, specular 0.8): NRC's arrival record j and
    NIRC's departure record j - 1 of the *same* path (same seed, same core)
    estimate the same radiance, reflected at x_j toward x_{j-1}; NRC stores it
    divided by max(diffuse + specular albedo, 0.01) = 1.1.

    The specular reflectance is given explicitly: Mitsuba's plastics have no
    ``specular_reflectance`` attribute when it is left at its default (1), and
    the cache inputs then read 0 for it."""
    bsdf = {"type": "roughplastic", "alpha": 0.3,
            "diffuse_reflectance": {"type": "rgb", "value": [0.3] * 3},
            "specular_reflectance": {"type": "rgb", "value": [0.8] * 3}}
    scene = _furnace(mi, bsdf=bsdf)
    _, nrc_trainer, _ = _trainer(mi, scene, "nrc", self_training=False)
    _, nirc_trainer, _ = _trainer(mi, scene, "nirc")
    n = 1 << 14
    valid_a, target_a, records = _records(nrc_trainer, scene, seed=5, n_paths=n)
    valid_d, target_d, _ = _records(nirc_trainer, scene, seed=5, n_paths=n)
    albedo, albedo_spec = records["albedo"], records["albedo_spec"]
    np.testing.assert_allclose(albedo[valid_a], 0.3, rtol=1e-5)
    np.testing.assert_allclose(albedo_spec[valid_a], 0.8, rtol=1e-5)
    for j in range(1, RECORD_DEPTH):
        both = valid_a[:, j] & valid_d[:, j - 1]
        assert both.mean() > 0.9
        np.testing.assert_allclose(target_a[both, j] * 1.1, target_d[both, j - 1],
                                   rtol=1e-4, atol=1e-6)
        assert np.abs(target_d[both, j - 1]).mean() > 0.1  # not trivially zero


def test_nrc_query_multiplies_the_demodulation_back(mi):
    """An NRC render with a constant demodulated cache output C that terminates
    at x_1 (tiny spread constant): L = L_e + rho L_e (emission, direct light at
    x_0) + rho * C * rho (the cache term times the albedo at x_1)."""
    from renderers.methods import nrc
    from tests.support.moments import render_moments

    value = 3.0
    scene = _furnace(mi)
    integrator, _, _ = nrc.build(_loaded(scene), parse_params("nrc", {"sph_c": 1e-9}), seed=3)
    integrator.cache = ConstantCache(value)
    mean, var = render_moments(scene, integrator, 256, seed=9)
    mean_y, var_y = mean[..., 1:2], var[..., 1:2]
    expected = LE + RHO * LE + RHO * value * RHO
    result = agreement_test(mean_y, var_y, np.full_like(mean_y, expected),
                            np.zeros_like(var_y), alpha=0.001)
    assert result.passed, f"expected {expected}, got {mean_y.mean():.5f}: {result.summary()}"


@pytest.mark.parametrize("bsdf, albedo, albedo_spec", [
    ({"type": "diffuse"}, 0.5, 0.0),
    ({"type": "roughconductor"}, 0.0, 1.0),     # generic diffuse reflectance was 25
    ({"type": "plastic"}, 0.5, 1.0),            # unset specular_reflectance read as 0
    ({"type": "plastic", "specular_reflectance": 0.25}, 0.5, 0.25),
    ({"type": "dielectric"}, 0.0, 1.0),
])
def test_cache_albedo_inputs_follow_the_bsdf_lobes(mi, bsdf, albedo, albedo_spec):
    """NRC's albedo inputs (and so its demodulation factor) on common BSDFs."""
    import drjit as dr

    from renderers.integrators.cached import cache_inputs

    si = dr.zeros(mi.SurfaceInteraction3f)
    si.n = mi.Normal3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(si.n)
    si.wi = mi.Vector3f(0, 0, 1)
    loaded = mi.load_dict(bsdf)        # kept alive: the pointer array does not own it
    inputs = cache_inputs(si, mi.BSDFPtr(loaded), specular=True)
    assert np.allclose(np.asarray(inputs["albedo"]), albedo)
    assert np.allclose(np.asarray(inputs["albedo_spec"]), albedo_spec)
