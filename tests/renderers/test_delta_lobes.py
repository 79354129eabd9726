"""Emitters seen through delta lobes: every method that declares itself unbiased either
renders them or refuses the scene.

At a mirror, the coating of smooth plastic or glass, the BSDF has no value to
evaluate: the light it reflects reaches the pixel only through a BSDF sample
(Mitsuba's ``path`` collects that emitter hit with MIS weight 1). A method whose
light samples evaluate the BSDF (ReSTIR's target) misses it unless it adds that
sample: `restir-di` rendered those pixels black before.

``MIRROR_LIGHTS``: a floor, a mirror facing the camera and a smooth plastic sphere,
lit by two area lights behind the camera that the camera sees only in the mirror
and the sphere. ``MIRROR_SKY``: the same with a constant environment instead (for
the methods that need one). Every method of the registry that declares itself
unbiased (``Method.unbiased``, or its ``estimator`` set to ``unbiased``) runs
through its own frame loop at max_depth 2 (direct light at the first hit, the
depth of the primary-hit methods), K = 8 seeds of one frame of 128 spp, and its
seeds' mean of luminance is tested against ``path`` at max_depth 2 with the
per-pixel Šidák test and the aggregate tile test (the seeds' variance: K - 1
degrees of freedom); methods whose pixels share samples take the image-mean test
instead of the tile test. A method that does not apply to a scene must say why
(its ``applies_to``). Planted: `restir-di` without its delta-lobe sample is
rejected.
"""

from __future__ import annotations

from typing import Any, Literal, get_args, get_origin

import numpy as np
import pytest

from metrics.statistics import agreement_test, image_mean_test, z_test
from renderers.methods import METHODS
from tests.renderers.lighting import luminance_moments
from tests.renderers.scene_xml import perspective_sensor
from tests.support.moments import render_moments
from tests.support.untimed import UNTIMED

RES = 16
#: K seeds of SPP samples: 1024 samples per pixel in all. A seed's cost is mostly the
#: frame loop's fixed part (training, warm-up), so 8 seeds of 128 spp take about half the
#: time of 16 of 64 with as many samples (only the seeds' variance has 7 degrees of
#: freedom instead of 15, which the tests' Student t accounts for).
SEEDS = 8
SPP = 128
REFERENCE_SPP = 8192
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])  # Y of linear sRGB (mi.luminance)

_ROOM = """<scene version="3.0.0">
    """ + perspective_sensor("50", "0, 1.2, 4", "0, 0.8, -1") + """
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale value="3"/></transform>
        <bsdf type="diffuse"/>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale x="1.5" y="1"/><translate y="1" z="-1"/></transform>
        <bsdf type="conductor"/>
    </shape>
    <shape type="sphere">
        <point name="center" value="1.2, 0.4, 0.5"/><float name="radius" value="0.4"/>
        <bsdf type="plastic"/>
    </shape>
    {lights}
</scene>
"""
#: Two one-sided lights behind the camera, facing the mirror.
MIRROR_LIGHTS = _ROOM.replace("{lights}", """
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.6"/><rotate y="1" angle="180"/>
            <translate x="-0.5" y="1.5" z="5"/></transform>
        <emitter type="area"><rgb name="radiance" value="30, 30, 30"/></emitter>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.4"/><rotate y="1" angle="180"/>
            <translate x="0.6" y="0.8" z="5"/></transform>
        <emitter type="area"><rgb name="radiance" value="10, 40, 20"/></emitter>
    </shape>""")
MIRROR_SKY = _ROOM.replace("{lights}", """
    <emitter type="constant"><rgb name="radiance" value="0.8, 0.9, 1.2"/></emitter>""")


def unbiased_variants() -> list[tuple[str, dict[str, Any]]]:
    """(method, parameters) of every method that declares itself unbiased."""
    variants = []
    for name, method in METHODS.items():
        field = method.params.model_fields.get("estimator")
        if field is not None and get_origin(field.annotation) is Literal:
            if "unbiased" in get_args(field.annotation):
                variants.append((name, {"estimator": "unbiased"}))
        elif method.unbiased is True:
            variants.append((name, {}))
    return variants


def _load(tmp_path_factory, xml: str) -> Any:
    from renderers.scenes import load_scene

    path = tmp_path_factory.mktemp("delta") / "scene.xml"
    path.write_text(xml.replace("{res}", str(RES)))
    return load_scene(str(path), RES)


@pytest.fixture(scope="module")
def scenes(mi, tmp_path_factory) -> dict[str, tuple[Any, tuple[np.ndarray, np.ndarray]]]:
    """Each scene and its reference: ``path`` at max_depth 2, luminance moments."""
    loaded = {}
    for name, xml in (("mirror-lights", MIRROR_LIGHTS), ("mirror-sky", MIRROR_SKY)):
        scene = _load(tmp_path_factory, xml)
        reference = luminance_moments(render_moments(
            scene.scene, {"type": "path", "max_depth": 2}, REFERENCE_SPP, seed=7))
        loaded[name] = (scene, reference)
    return loaded


def _seed_luminance(scene: Any, method: str, params: dict[str, Any]) -> np.ndarray:
    """(K, H, W) luminance of K seeds of the method's frame loop at max_depth 2."""
    from renderers.methods import parse_params

    parsed = parse_params(method, {**params, "max_depth": 2})
    images = [METHODS[method].render(scene, parsed, seed_parts=("delta", method, k),
                                     spp=SPP, frames=1, hooks=UNTIMED).accumulated[..., :3]
              @ LUMINANCE
              for k in range(SEEDS)]
    return np.stack(images)


def _agrees(seeds: np.ndarray, reference: tuple[np.ndarray, np.ndarray],
            correlated_pixels: bool) -> tuple[bool, str]:
    mean, variance = seeds.mean(axis=0), seeds.var(axis=0, ddof=1) / len(seeds)
    if correlated_pixels:
        pixels = z_test(mean, variance, *reference, alpha=0.01, dof=len(seeds) - 1)
        image = image_mean_test(seeds[..., None], reference[0][..., None],
                                reference[1][..., None], alpha=0.01)
        return pixels.passed and image.passed, f"{pixels.summary()}; {image.summary()}"
    result = agreement_test(mean, variance, *reference, dof=len(seeds) - 1, alpha=0.01)
    return result.passed, result.summary()


def _scene_for(method: str, scenes) -> str | None:
    """The first scene the method applies to (None: neither)."""
    for name, (scene, _) in scenes.items():
        if METHODS[method].applies_to(scene.features)[0]:
            return name
    return None


@pytest.mark.parametrize("method, params", unbiased_variants(),
                         ids=[name for name, _ in unbiased_variants()])
def test_an_unbiased_method_renders_emitters_seen_through_delta_lobes(scenes, method, params):
    chosen = _scene_for(method, scenes)
    if chosen is None:
        # Taking neither mirror scene is allowed only as a refusal of their delta lobes,
        # named as such, of a method that takes the same scene without them.
        assert _refuses_delta_lobes(method, scenes), f"{method} applies to neither mirror scene"
        return
    scene, reference = scenes[chosen]
    assert scene.features.has_delta
    passed, summary = _agrees(_seed_luminance(scene, method, params), reference,
                              METHODS[method].correlated_pixels)
    print(method, chosen, summary)
    assert passed, summary


@pytest.mark.parametrize("method", [name for name, _ in unbiased_variants()])
def test_a_method_that_refuses_the_mirror_and_lights_says_why(scenes, method):
    applies, reason = METHODS[method].applies_to(scenes["mirror-lights"][0].features)
    if not applies:
        # The environment methods refuse it for the environment it lacks; the control
        # variates, whose mixture sampling draws smooth lobes only, for its delta lobes.
        assert reason == "no environment map" or _refuses_delta_lobes(method, scenes), (
            method, reason)


def _refuses_delta_lobes(method: str, scenes) -> bool:
    """The method refuses both mirror scenes for their delta lobes and names them, and
    takes the same scene without them (its refusal is of the lobes, nothing else)."""
    from dataclasses import replace

    reasons = [METHODS[method].applies_to(scene.features) for scene, _ in scenes.values()]
    smooth = replace(scenes["mirror-lights"][0].features, has_delta=False)
    return (all(not applies and "delta BSDF lobe" in reason for applies, reason in reasons)
            and METHODS[method].applies_to(smooth)[0])


def test_restir_di_without_its_delta_lobe_sample_is_rejected(scenes, monkeypatch):
    """The check can fail: the estimator as it was, with the emission seen through a
    delta lobe left out, is rejected (its mirror pixels are black)."""
    import mitsuba as mi

    from renderers.integrators import restir

    monkeypatch.setattr(restir, "delta_emission", lambda *args: mi.Spectrum(0.0))
    scene, reference = scenes["mirror-lights"]
    passed, summary = _agrees(_seed_luminance(scene, "restir-di", {}), reference, True)
    print(summary)
    assert not passed
