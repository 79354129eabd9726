"""V_rel(<F_r>) of the residual estimator at the primary hit (docs/metrics.md).

A diffuse plane (albedo a) under a constant sky L: every continuation from the
primary hit escapes to the sky, whose light is direct light, so the residual
sample is -n(x, w) a (cosine sampling: f cos / p = a). With a cache that is c
inside the cone cos(theta) > 1/2 and 0 outside, P(inside) = 3/4 under cosine
sampling (cos² theta is uniform), so the residual is -a c B with B Bernoulli(3/4):
Var = a² c² 3/16, and the reference is R = a L. The probe's samples, through the
helpers the executor stores V_rel with, must give a² c² (3/16) / (R² + eps).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from metrics.residual_variance import relative_residual_variance, residual_variance_map

ALBEDO, SKY, CONE_VALUE, EPS = 0.5, 1.0, 1.0, 0.01
RES, SPP = 16, 8

PLANE = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, 0, 1" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm"><integer name="width" value="{res}"/>
            <integer name="height" value="{res}"/><rfilter type="box"/></film>
        <sampler type="independent"/>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="{sky}"/></emitter>
    <shape type="rectangle">
        <transform name="to_world"><scale value="100"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="{albedo}"/></bsdf>
    </shape>
</scene>"""


class ConeCache:
    """n(x, w) = c where w is within 60 degrees of the plane's normal (+z), else 0."""

    def surface_features(self, position: Any, **_inputs: Any) -> list[Any]:
        import mitsuba as mi

        return [mi.Point3f(position)]

    def query(self, surface: Any, direction: Any) -> Any:
        import drjit as dr
        import mitsuba as mi

        return mi.Color3f(dr.select(direction.z > 0.5, CONE_VALUE, 0.0))


def _probe_v_rel(mi, normalise=relative_residual_variance) -> tuple[float, np.ndarray]:
    from renderers.integrators import register_plugins
    from renderers.integrators.residual_probe import ResidualProbe
    from renderers.methods import parse_params

    register_plugins()
    scene = mi.load_string(PLANE.format(res=RES, sky=SKY, albedo=ALBEDO))
    params = parse_params("nirc", {"estimator": "unbiased", "nc": [1]})
    probe = mi.load_dict({"type": ResidualProbe.plugin_name, **params.core()})
    probe.configure(params)
    probe.cache = ConeCache()
    values, probed = probe.residual_samples(scene, SPP, seed=7)
    assert probed.all()   # every primary hit is the plane
    variance, nonfinite = residual_variance_map(values, probed)
    assert nonfinite == 0
    reference = np.full((RES, RES, 3), ALBEDO * SKY)
    per_pixel = variance / (reference ** 2 + EPS)
    return normalise(variance, reference, EPS), per_pixel.mean(axis=-1).ravel()


def _dividing_by_the_mean(variance: np.ndarray, reference: np.ndarray, eps: float) -> float:
    """A planted wrong normalisation: the reference instead of its square."""
    return float(np.mean(variance / (reference + eps)))


@pytest.mark.parametrize("normalise, holds", [(relative_residual_variance, True),
                                              (_dividing_by_the_mean, False)])
def test_v_rel_of_a_known_residual(mi, normalise, holds):
    expected = (ALBEDO * CONE_VALUE) ** 2 * 3 / 16 / ((ALBEDO * SKY) ** 2 + EPS)
    v_rel, per_pixel = _probe_v_rel(mi, normalise)
    # The pixels' S² are independent: a z-test of their mean (4 standard errors).
    standard_error = per_pixel.std(ddof=1) / np.sqrt(per_pixel.size)
    assert (abs(v_rel - expected) < 4 * standard_error) == holds, (v_rel, expected,
                                                                  standard_error)


def test_variance_map_leaves_out_pixels_without_two_finite_samples():
    values = np.zeros((1, 3, 3, 3))
    values[0, 0] = [[1, 1, 1], [3, 3, 3], [9, 9, 9]]
    values[0, 1, 2] = np.nan
    probed = np.array([[[True, True, False], [True, True, True], [True, False, False]]])
    variance, nonfinite = residual_variance_map(values, probed)
    assert nonfinite == 1
    np.testing.assert_allclose(variance[0, 0], np.var([1, 3], ddof=1))
    assert np.isnan(variance[0, 1:]).all()
    assert relative_residual_variance(variance[:, 1:], np.ones((1, 2, 3)), EPS) is None


def test_a_huge_but_finite_variance_stays_finite():
    """Samples of 1e20 (float32, as the probe returns them) have a variance past float32's
    range: it is computed and kept in float64, not turned into inf and then left out."""
    values = np.full((1, 1, 4, 3), 1e20, np.float32)
    values[0, 0, 0] = 0.0
    variance, nonfinite = residual_variance_map(values, np.ones((1, 1, 4), bool))
    assert nonfinite == 0 and np.isfinite(variance).all()
    np.testing.assert_allclose(variance, 2.5e39, rtol=1e-6)
    assert relative_residual_variance(variance, np.full((1, 1, 3), 1e20), EPS) \
        == pytest.approx(0.25, rel=1e-6)
