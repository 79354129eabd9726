"""Control variates with a closed-form integral at first hits (`cv-sh`; NIRC paper Eq. 7,
Sec. 6.1): the closed form, unbiasedness with power, and planted errors rejected.

Every render test compares per-pixel means and variances (Mitsuba's ``moment``
integrator, tests/support/moments.py) with the per-pixel Šidák z-test and the
block test (metrics.statistics.agreement_test), at 8x8 pixels. The statistics:

* a zero model (g = 0: the plain mixture-sampled estimator) and a fitted model agree
  with Mitsuba's ``path`` at the same depth, and the fitted model is far from zero
  (its integral carries most of the pixel) and lowers the variance;
* an oracle-like case, a diffuse plane under a constant sky, whose expectation rho L
  is known in closed form: the fitted model agrees with it and cuts the variance
  several-fold (a clamped cosine is smooth: 5 SH bands fit it well);
* planted: the closed-form integral scaled by 1.05, and G over the whole sphere with
  BSDF-only sampling (q = 0 below the surface), are both rejected.
"""

from __future__ import annotations

import numpy as np
import pytest

from metrics.statistics import agreement_test
from renderers.methods import MethodError, get_method, parse_params
from tests.renderers.scene_xml import perspective_sensor
from tests.support.moments import render_moments

RES = 8
SPP = 1024
#: Diffuse floor and box, a rough-metal sphere, a large area light and a coloured sky:
#: every first hit sees smooth BSDFs (the method refuses delta lobes).
MIXED = """<scene version="3.0.0">
    """ + perspective_sensor("50", "0, 1.5, 4", "0, 0.3, 0") + """
    <emitter type="constant"><rgb name="radiance" value="0.4, 0.5, 0.7"/></emitter>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale value="3"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf>
    </shape>
    <shape type="sphere">
        <point name="center" value="-0.6, 0.5, 0"/><float name="radius" value="0.5"/>
        <bsdf type="roughconductor"><float name="alpha" value="0.3"/></bsdf>
    </shape>
    <shape type="cube">
        <transform name="to_world"><scale value="0.4"/><translate x="0.7" y="0.4" z="0.2"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.3, 0.7, 0.3"/></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="90"/><scale value="1.5"/><translate y="2.5"/></transform>
        <emitter type="area"><rgb name="radiance" value="3, 2.5, 2"/></emitter>
    </shape>
</scene>
"""
#: A diffuse plane (albedo RHO) filling the view under a constant sky SKY: every pixel's
#: radiance is RHO * SKY (Eq. 1 with L_i = SKY on the upper hemisphere).
RHO, SKY = 0.5, 0.8
PLANE = """<scene version="3.0.0">
    """ + perspective_sensor("40", "0, 1, 0", "0, 0, 0.001") + f"""
    <emitter type="constant"><rgb name="radiance" value="{SKY}"/></emitter>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale value="50"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="{RHO}"/></bsdf>
    </shape>
</scene>
"""


def _load(tmp_path_factory, xml: str):
    """The scene as the methods load it (its Mitsuba scene is ``.scene``)."""
    from renderers.scenes import load_scene

    path = tmp_path_factory.mktemp("cv") / "scene.xml"
    path.write_text(xml.replace("{res}", str(RES)))
    return load_scene(str(path), RES)


@pytest.fixture(scope="module")
def mixed(mi, tmp_path_factory):
    return _load(tmp_path_factory, MIXED)


@pytest.fixture(scope="module")
def plane(mi, tmp_path_factory):
    return _load(tmp_path_factory, PLANE)


def _integrator(mi, model, cls=None, max_depth=2):
    from renderers.integrators import control_variate, register_plugins

    register_plugins()
    if cls is None:
        integrator = mi.load_dict({"type": control_variate.PLUGIN_NAME, "max_depth": max_depth})
    else:
        props = mi.Properties()
        props["max_depth"] = max_depth
        integrator = cls(props)
    return integrator.with_model(model)


#: Fitting of each model: (frames, spp) before its fit is frozen. SH projects every
#: sample alike, so two frames suffice; stepwise EM takes one batch per frame. The
#: method renders below use the same spp: the lanes' pixel index divides by it, so
#: another spp compiles another kernel.
FITS = {"sh": (2, 256), "vmf": (8, 32)}


def _model(kind: str):
    """A zero (unfitted) model: SH at the paper's 5 bands, or a vMF mixture of 3 lobes
    (11 lobes compile a kernel several times larger; the fingerprint test renders
    them)."""
    from renderers.caches.sh import SHConfig, SHModel
    from renderers.caches.vmf import VMFConfig, VMFModel

    if kind == "sh":
        return SHModel(SHConfig(), RES * RES)
    return VMFModel(VMFConfig(lobes=3), RES * RES)


def _fitted(mi, scene, kind="sh", fit=None):
    """(integrator, model) fitted from ``fit`` = (frames, spp) (the model's FITS by
    default), the fit then frozen (the moment renders below record nothing)."""
    model = _model(kind)
    integrator = _integrator(mi, model)
    frames, spp = fit or FITS[kind]
    for frame in range(frames):
        mi.render(scene.scene, integrator=integrator, spp=spp, seed=1000 + frame)
        model.fit(integrator.records)
    integrator.fitting = False
    return integrator, model


class ScaledIntegral:
    """Planted: a model whose closed-form integral is 1.05 times the true one."""

    def __init__(self, model) -> None:
        self.model = model

    def eval(self, pixel, w, active):
        return self.model.eval(pixel, w, active)

    def integral(self, pixel, active):
        return 1.05 * self.model.integral(pixel, active)

    def fit(self, records):
        """Fits nothing: the fit is frozen."""


def _bsdf_only(mi):
    """Planted: the integrator with BSDF-only sampling (q = p_bsdf, 0 below the surface)
    but G still over the whole sphere."""
    from renderers.integrators.cached import smooth_context
    from renderers.integrators.control_variate import ControlVariateIntegrator

    class BSDFOnly(ControlVariateIntegrator):
        def sample_direction(self, si, bsdf, sampler, active):
            sampler.next_1d(active)
            bs, _ = bsdf.sample(smooth_context(), si, sampler.next_1d(active),
                                sampler.next_2d(active), active)
            produced = active & (bs.pdf > 0)
            f_cos = bsdf.eval(smooth_context(), si, bs.wo, produced)
            return bs.wo, f_cos, mi.Float(bs.pdf), produced

    return BSDFOnly


def test_sh_integral_is_the_quadrature_of_the_model(mi):
    """G = 2 sqrt(pi) c_0 equals the integral of g over the sphere (Gauss-Legendre in
    cos theta x uniform phi: exact for these polynomials) for random coefficients, and
    the basis is orthonormal; a basis without its normalisation would fail both."""
    import drjit as dr

    from renderers.caches.sh import SHConfig, SHModel

    z, wz = np.polynomial.legendre.leggauss(16)
    phi = (np.arange(32) + 0.5) * 2 * np.pi / 32
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    weights = (wz[:, None] * np.full_like(pp, 2 * np.pi / 32)).ravel()
    r = np.sqrt(1 - zz**2)
    w = mi.Vector3f(*(a.ravel() for a in (r * np.cos(pp), r * np.sin(pp), zz)))
    basis = np.array([np.broadcast_to(np.asarray(y, dtype=np.float64), weights.shape)
                      for y in dr.sh_eval(w, 4)])
    np.testing.assert_allclose((basis * weights) @ basis.T, np.eye(25), atol=1e-5)

    model = SHModel(SHConfig(), 2)
    random = np.random.default_rng(3).normal(size=(25, 3, 2))
    model.coefficients = [[mi.Float(values) for values in k] for k in random]
    for pixel in range(2):
        index = mi.UInt32(np.full(weights.size, pixel))
        g = np.asarray(model.eval(index, w, True))           # (channels, directions)
        G = np.asarray(model.integral(mi.UInt32(pixel), True)).ravel()
        np.testing.assert_allclose(g @ weights, G, rtol=1e-5, atol=1e-5)


@pytest.fixture(scope="module")
def reference(mixed):
    return render_moments(mixed.scene, {"type": "path", "max_depth": 2}, SPP, seed=2)


@pytest.fixture(scope="module")
def zero_moments(mi, mixed):
    zero = _integrator(mi, _model("sh"))
    zero.fitting = False
    return render_moments(mixed.scene, zero, SPP, seed=1)


def test_the_zero_model_agrees_with_the_reference(zero_moments, reference):
    """g = 0: the plain estimator, mixture-sampled."""
    result = agreement_test(*zero_moments, *reference)
    assert result.passed, result.summary()


@pytest.mark.parametrize("kind", ["sh", "vmf"])
def test_a_fitted_model_agrees_with_the_reference_and_lowers_variance(mi, mixed, reference,
                                                                     zero_moments, kind):
    """The fitted g agrees with ``path``, is far from zero (its integral is most of the
    pixel) and lowers the variance where the pixels see a surface."""
    integrator, model = _fitted(mi, mixed, kind)
    mean_g, var_g = render_moments(mixed.scene, integrator, SPP, seed=3)
    result = agreement_test(mean_g, var_g, *reference)
    assert result.passed, result.summary()
    var_0 = zero_moments[1]
    surface = var_0[..., 1] > 1e-6   # the sky's pixels have no variance to lower
    G = np.asarray(model.integral(mi.UInt32(np.arange(RES * RES)), True)).T
    assert np.median(G.reshape(RES, RES, 3)[surface] / mean_g[surface]) > 0.5
    ratio = np.median(var_g[surface] / var_0[surface])
    assert ratio < 0.9, f"median variance ratio fitted / zero model {ratio:.2f}"

    integrator.with_model(ScaledIntegral(model))
    assert not agreement_test(*render_moments(mixed.scene, integrator, SPP, seed=4),
                              *reference).passed


def test_a_full_sphere_integral_with_bsdf_only_sampling_is_rejected(mi, mixed, reference):
    """G over the sphere while q = 0 below the surface misses -int_{q=0} g."""
    _, model = _fitted(mi, mixed)
    bsdf_only = _integrator(mi, model, cls=_bsdf_only(mi))
    bsdf_only.fitting = False
    assert not agreement_test(*render_moments(mixed.scene, bsdf_only, SPP, seed=5),
                              *reference).passed


def test_plane_under_a_constant_sky_has_the_known_expectation(mi, plane):
    """Oracle-like: every pixel's expectation is RHO * SKY (grey: its XYZ is the white
    point times it, as the moment renders convert). The fitted SH model agrees with it
    from 4 x 256 samples and lowers the variance at least twofold (a clamped cosine is
    smooth: measured 0.23)."""
    from tests.support.moments import FLOAT32_REL_PRECISION

    value = np.asarray(mi.srgb_to_xyz(mi.ScalarColor3f(RHO * SKY))).ravel()
    expected = (np.broadcast_to(value, (RES, RES, 3)),
                np.broadcast_to((FLOAT32_REL_PRECISION * value) ** 2, (RES, RES, 3)))
    zero = _integrator(mi, _model("sh"))
    zero.fitting = False
    _, var_0 = render_moments(plane.scene, zero, 256, seed=1)
    integrator, _ = _fitted(mi, plane, fit=(4, 256))
    mean_g, var_g = render_moments(plane.scene, integrator, 256, seed=2)
    result = agreement_test(mean_g, var_g, *expected)
    assert result.passed, result.summary()
    ratio = np.median(var_g / var_0)
    assert ratio < 0.5, f"median variance ratio fitted / zero model {ratio:.3f}"


@pytest.mark.parametrize("name, params, floats", [
    ("cv-sh", {}, {"model": 3 * 25, "fit": 3 * 25 + 1}),
    ("cv-vmf", {"vmf": {"lobes": 3}}, {"model": 7 * 3, "fit": 3 * 3 + 1}),
])
def test_a_cv_render_is_reproducible_and_stores_its_memory(mi, mixed, name, params, floats):
    from tests.support.untimed import UNTIMED

    method = get_method(name)
    values = parse_params(name, {"max_depth": 2, "pretrain_frames": 1, **params})
    spp = FITS[name.removeprefix("cv-")][1]
    a, b = (method.render(mixed, values, seed_parts=("cv",), spp=spp, frames=2,
                          hooks=UNTIMED) for _ in range(2))
    np.testing.assert_array_equal(a.accumulated, b.accumulated)
    model = a.method_stats["model"]
    assert model["floats_per_pixel"] == floats
    assert model["nonfinite_samples"] == 0
    assert set(a.timings["stages"]) == {"render", "fit"}


@pytest.mark.parametrize("name, values, fragment", [
    ("cv-sh", {"max_depth": 1}, "max_depth"),
    ("cv-sh", {"uniform_fraction": 0.0}, "uniform_fraction"),
    ("cv-sh", {"sh": {"bands": 0}}, "sh: bands"),
    ("cv-sh", {"sh": {"lobes": 3}}, "sh: lobes"),
    ("cv-vmf", {"vmf": {"lobes": 0}}, "vmf: lobes"),
    ("cv-vmf", {"vmf": {"step_exponent": 0.5}}, "vmf: step_exponent"),
])
def test_invalid_cv_parameters(name, values, fragment):
    with pytest.raises(MethodError, match=fragment):
        parse_params(name, values)


@pytest.mark.parametrize("name", ["cv-sh", "cv-vmf"])
def test_cv_methods_refuse_delta_lobes_and_delta_emitters(name):
    from types import SimpleNamespace

    def features(**changes):
        return SimpleNamespace(**{"shape_count": 2, "emitter_count": 2, "area_emitter_count": 1,
                                  "has_envmap": True, "has_delta": False, **changes})

    method = get_method(name)
    assert method.applies_to(features()) == (True, "")
    assert "delta BSDF" in method.applies_to(features(has_delta=True))[1]
    assert "delta emitter" in method.applies_to(features(has_envmap=False))[1]


def test_vmf_lobes_integrate_to_one_and_start_spread_over_the_sphere(mi):
    """The normalised lobe integrates to 1 (so G = sum of amplitudes) from nearly uniform
    to narrow lobes, and the Fibonacci lattice leaves no lobe far from the others."""
    from renderers.caches.vmf import VMFConfig, VMFModel, fibonacci_directions

    z, wz = np.polynomial.legendre.leggauss(200)
    phi = (np.arange(64) + 0.5) * 2 * np.pi / 64
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    weights = (wz[:, None] * np.full_like(pp, 2 * np.pi / 64)).ravel()
    r = np.sqrt(1 - zz**2)
    w = mi.Vector3f(*(a.ravel() for a in (r * np.cos(pp), r * np.sin(pp), zz)))
    for kappa in (1e-3, 1.0, 50.0):
        model = VMFModel(VMFConfig(lobes=1, initial_kappa=kappa), 1)
        model.amplitude[:] = 1.0
        model.mean[:] = (0.0, 0.0, 1.0)
        model._upload()
        g = np.asarray(model.eval(mi.UInt32(np.zeros(weights.size, dtype=np.uint32)), w, True))
        assert g[0] @ weights == pytest.approx(1.0, rel=1e-4), kappa

    lattice = fibonacci_directions(11)
    np.testing.assert_allclose(np.linalg.norm(lattice, axis=1), 1.0, rtol=1e-12)
    cosines = lattice @ lattice.T - 2 * np.eye(11)
    # 11 points spread evenly: each has a neighbour within ~70 degrees, none closer than ~45.
    assert 0.3 < cosines.max(axis=1).min() and cosines.max() < 0.75


def test_each_frame_uses_the_model_fitted_from_the_frames_before_it(mi, mixed):
    """The method's frame t renders with g fitted from frames 0..t-1 only: its frames
    equal renders of the same seeds with the model updated between them (frame 0 with
    g = 0); a schedule that folded a frame's own samples in first would differ."""
    from renderers.methods.base import FrameHooks
    from renderers.seeding import derive_seed

    params = parse_params("cv-sh", {"max_depth": 2})
    spp = FITS["sh"][1]
    out = get_method("cv-sh").render(mixed, params, seed_parts=("order",), spp=spp, frames=2,
                                     hooks=FrameHooks(keep_frames=True, warmup=False,
                                                      kernel_every=0))
    model = _model("sh")
    integrator = _integrator(mi, model)
    for index, frame in enumerate(out.frames):
        image = mi.render(mixed.scene, integrator=integrator, spp=spp,
                          seed=derive_seed("order", index))
        np.testing.assert_array_equal(frame, np.asarray(image)[..., :3])
        model.fit(integrator.records)
