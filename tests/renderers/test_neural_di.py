"""`neural-di` (renderers.integrators.neural_di) and its closed-form polygon light term.

The estimator is L_e + Σ_k U_k V_k at primary hits, so its reference is
Mitsuba's ``path`` at max_depth 2. With exact visibility its expectation is
that reference wherever visibility is constant over each light (docs/
estimators.md, "neural-di"), which these test scenes are built for:

* POLYGONS: a checkered floor (one-sided diffuse) under a rectangle light, a
  steep triangle light (an OBJ; part of the floor sees its back) and a
  vertical rectangle light at the floor's back edge that reaches below the
  floor (its lower part is below every floor point's horizon: the clip). No
  point of the floor has any light partly hidden, so V = 1 and the test is of
  U_k alone: per-pixel Šidák z-test and aggregate test against ``path``.
* DIVIDED: a floor split by a wall higher than the two lights, one light on
  each side: every surface point sees a light either whole or not at all.
  With :class:`TracedVisibility` (the oracle cache: the cache's training
  target, traced) the estimator agrees with ``path``.
* Planted: U_k without the horizon clip, and U_k a factor π too large (the
  BRDF's 1/π missing), are rejected by the same test.

Noise: on `many-lights` seen from below the lights, the per-pixel variance
over seeds of a 1-spp frame (what is left: the pixel footprint) is far below
``path``'s. Bias: with the trained cache it is measured and printed, and it
must fall with training (an untrained cache is worse); its size is reported,
not asserted.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from metrics.errors import bias_variance
from metrics.statistics import agreement_test
from tests.renderers.lighting import luminance_moments
from tests.renderers.scene_xml import perspective_sensor
from tests.support.moments import render_moments

RES = 16
SPP = 1024
REFERENCE_SPP = 4096
BLACK = '<bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>'

#: A triangle whose face normal (0, -0.8, 1.6) faces down and toward the camera.
TRIANGLE_OBJ = """v 1.0 1.5 -0.5
v 2.0 1.5 -0.5
v 1.5 3.1 0.3
f 1 2 3
"""

POLYGONS = """<scene version="3.0.0">
    """ + perspective_sensor("60", "0, 3, 4.5", "0, 0, -0.5") + """
    <shape type="rectangle">
        <transform name="to_world"><scale value="2"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse">
            <texture type="checkerboard" name="reflectance">
                <rgb name="color0" value="0.2, 0.25, 0.3"/><rgb name="color1" value="0.7, 0.6, 0.5"/>
                <transform name="to_uv"><scale x="4" y="4"/></transform>
            </texture>
        </bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.3"/><rotate x="1" angle="90"/>
            <translate x="-1.2" y="1.5"/></transform>
        """ + BLACK + """
        <emitter type="area"><rgb name="radiance" value="10, 8, 6"/></emitter>
    </shape>
    <shape type="obj">
        <string name="filename" value="{triangle}"/>
        <boolean name="face_normals" value="true"/>
        """ + BLACK + """
        <emitter type="area"><rgb name="radiance" value="3, 5, 8"/></emitter>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale x="0.8" y="0.8"/><translate y="-0.2" z="-2.05"/></transform>
        """ + BLACK + """
        <emitter type="area"><rgb name="radiance" value="6, 6, 4"/></emitter>
    </shape>
</scene>
"""

DIVIDED = """<scene version="3.0.0">
    """ + perspective_sensor("60", "0, 4, 4", "0, 0, 0") + """
    <shape type="rectangle">
        <transform name="to_world"><scale value="2"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="twosided"><bsdf type="diffuse"/></bsdf>
    </shape>
    <shape type="cube">
        <transform name="to_world"><scale x="0.05" y="1" z="2"/><translate y="1"/></transform>
        <bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.4, 0.3"/></bsdf></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.3"/><rotate x="1" angle="90"/>
            <translate x="-1" y="1.5"/></transform>
        """ + BLACK + """
        <emitter type="area"><rgb name="radiance" value="10, 8, 6"/></emitter>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.3"/><rotate x="1" angle="90"/>
            <translate x="1" y="1.5" z="0.5"/></transform>
        """ + BLACK + """
        <emitter type="area"><rgb name="radiance" value="4, 6, 9"/></emitter>
    </shape>
</scene>
"""


@pytest.fixture(scope="module")
def polygons(mi, tmp_path_factory):
    obj = tmp_path_factory.mktemp("neural-di") / "triangle.obj"
    obj.write_text(TRIANGLE_OBJ)
    return mi.load_string(POLYGONS.format(res=RES, triangle=obj))


@pytest.fixture(scope="module")
def divided(mi):
    return mi.load_string(DIVIDED.format(res=RES))


def _reference(scene, spp=REFERENCE_SPP, seed=1000):
    return luminance_moments(render_moments(scene, {"type": "path", "max_depth": 2}, spp,
                                            seed=seed))


def _traced(mi, rays=1):
    """neural-di with the oracle visibility (shadow rays to the lights' area samples)."""
    from renderers.integrators import neural_di, register_plugins

    register_plugins()
    integrator = mi.load_dict({"type": neural_di.PLUGIN_NAME})
    return integrator.with_visibility(neural_di.TracedVisibility(rays))


def _agreement(scene, integrator, reference, seed=1):
    test = luminance_moments(render_moments(scene, integrator, SPP, seed=seed))
    result = agreement_test(*test, *reference, alpha=0.01)
    print(result.summary())
    return result


# ---------------------------------------------------------------------------
# Registration and applicability (fast, no Mitsuba)
# ---------------------------------------------------------------------------

def _features(emitters=2, polygons=None, shapes=4):
    return SimpleNamespace(emitter_count=emitters, shape_count=shapes,
                           polygon_emitter_count=emitters if polygons is None else polygons)


def test_registered_with_the_papers_defaults_and_a_fixed_depth():
    from renderers.methods import METHODS, MethodError, parse_params

    params = parse_params("neural-di", {})
    assert (params.max_depth, params.world_points, params.camera_points) == (2, 4096, 4096)
    with pytest.raises(MethodError, match="max_depth"):
        parse_params("neural-di", {"max_depth": 3})
    assert METHODS["neural-di"].version == 2


@pytest.mark.parametrize(("features", "reason"), [
    (_features(0), "no emitter"),
    (_features(33), "more than 32 emitters: one cache output per light"),
    (_features(2, polygons=1), "an emitter that is not a polygon (environment, delta or "
                               "curved area light): neural-di's unshadowed term is a "
                               "polygon integral"),
    (_features(2, shapes=0), "the scene has no surface to shade"),
    (_features(1), ""),
    (_features(32), ""),
])
def test_applies_to_states_why_not(features, reason):
    from renderers.methods import METHODS

    assert METHODS["neural-di"].applies_to(features) == (not reason, reason)


def test_a_sphere_light_is_refused_with_the_reason(mi):
    from renderers.integrators.polygon_lights import PolygonLights
    from renderers.scenes.features import compute_features

    scene = mi.load_string(DIVIDED.replace('<shape type="cube">', '<shape type="sphere">'
                                           '<emitter type="area"/></shape><shape type="cube">')
                           .format(res=RES))
    assert compute_features(scene, (RES, RES)).polygon_emitter_count == 2
    with pytest.raises(ValueError, match="is not a polygon"):
        PolygonLights(scene)


# ---------------------------------------------------------------------------
# The closed-form unshadowed term and the oracle cache (statistical)
# ---------------------------------------------------------------------------

def test_polygon_lights_match_path_where_nothing_is_hidden(mi, polygons):
    result = _agreement(polygons, _traced(mi), _reference(polygons))
    assert result.passed, result.summary()


def test_oracle_visibility_matches_path_where_lights_are_whole_or_hidden(mi, divided):
    result = _agreement(divided, _traced(mi), _reference(divided))
    assert result.passed, result.summary()


def _unclipped(p, n, v):
    """The planted bug: the edge sum over the whole triangle, no horizon clip (the part
    below the horizon subtracts instead of being left out)."""
    import drjit as dr
    import mitsuba as mi

    from renderers.integrators.polygon_lights import edge_vector

    a = [mi.Vector3f(vertex - p) for vertex in v]
    phi = 0.5 * (edge_vector(a[0], a[1]) + edge_vector(a[1], a[2]) + edge_vector(a[2], a[0]))
    in_front = dr.dot(-a[0], dr.cross(v[1] - v[0], v[2] - v[0])) > 0
    e = dr.dot(n, phi)
    return dr.select(in_front, dr.abs(e), 0.0), dr.select(in_front, dr.mulsign(phi, e), 0.0)


@pytest.mark.parametrize("bug", ["no horizon clip", "BRDF without 1/pi"])
def test_planted_errors_in_the_unshadowed_term_are_rejected(mi, polygons, monkeypatch, bug):
    from renderers.integrators import polygon_lights

    if bug == "no horizon clip":
        monkeypatch.setattr(polygon_lights, "triangle_irradiance", _unclipped)
    else:
        irradiance = polygon_lights.triangle_irradiance

        def times_pi(p, n, v):
            e, phi = irradiance(p, n, v)
            return e * math.pi, phi * math.pi

        monkeypatch.setattr(polygon_lights, "triangle_irradiance", times_pi)
    result = _agreement(polygons, _traced(mi), _reference(polygons), seed=2)
    assert not result.passed, result.summary()


# ---------------------------------------------------------------------------
# With the trained cache: noise and bias on `many-lights` (slow)
# ---------------------------------------------------------------------------

def _floor_view(mi, resolution):
    from renderers.scenes.many_lights import floor_view
    from renderers.scenes.parts import set_film_resolution

    scene = mi.load_dict(set_film_resolution(floor_view(), resolution, resolution),
                         optimize=False)
    return SimpleNamespace(scene=scene, resolution=(resolution, resolution))


def _trained(scene, frames, seed=0):
    """The neural-di integrator after ``frames`` frames of the NVC's online training."""
    from renderers.methods.neural_di import NeuralDIParams, build, train_frame
    from renderers.timing import StageTimer

    params = NeuralDIParams()
    integrator, cache = build(scene, params, seed)
    for frame in range(frames):
        train_frame(scene, cache, params, 100 * seed + frame, StageTimer())
    return integrator


def _renders(mi, scene, integrator, seeds):
    return [np.asarray(mi.render(scene, integrator=integrator, spp=1, seed=s))[..., :3]
            for s in seeds]


@pytest.mark.slow
def test_noise_free_at_one_spp_and_bias_falls_with_training(mi):
    """32 x 32, 8 seeds of a 1-spp frame. rVar of neural-di against path's (measured:
    see the printout); the trained cache's bias is reported, and below the untrained's."""
    scene = _floor_view(mi, 32)
    reference = np.asarray(mi.render(scene.scene, integrator=mi.load_dict(
        {"type": "path", "max_depth": 2}), spp=4096, seed=7))[..., :3]
    seeds = range(10, 18)
    pt = bias_variance(_renders(mi, scene.scene, mi.load_dict({"type": "path", "max_depth": 2}),
                                seeds), reference)
    untrained = bias_variance(_renders(mi, scene.scene, _trained(scene, 0), seeds), reference)
    trained = bias_variance(_renders(mi, scene.scene, _trained(scene, 64), seeds), reference)
    print(f"rVar: path {pt['rvar']:.4g}, neural-di {trained['rvar']:.4g} "
          f"(ratio {trained['rvar'] / pt['rvar']:.3g}); rBias^2: neural-di untrained "
          f"{untrained['rbias2']:.4g}, after 64 training frames {trained['rbias2']:.4g}")
    assert trained["rvar"] < 0.01 * pt["rvar"]
    assert trained["rbias2"] < 0.5 * untrained["rbias2"]
