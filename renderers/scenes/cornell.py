"""The Cornell box, diffuse (`cornell-box`) and glossy (`cornell-glossy`).

Both start from Mitsuba's own ``mi.cornell_box()`` so that `cornell-box` is
the scene every Mitsuba user knows, changed only where the benchmark needs it:
no integrator (renderers pass their own) and our camera film (box filter, RGB;
with the default Gaussian filter per-pixel estimates would not match
``mi.render``'s).
"""

from __future__ import annotations

from renderers.scenes.parts import (
    SENSOR_KEY,
    SceneDict,
    diffuse,
    film,
    rough_conductor,
    rough_plastic,
)
from renderers.scenes.runtime import mitsuba


def cornell_box() -> SceneDict:
    """Mitsuba's diffuse Cornell box with the benchmark's film and sampler."""
    scene = dict(mitsuba().cornell_box())
    # The renderer under test supplies the integrator; a scene must not.
    scene.pop("integrator", None)
    camera = dict(scene[SENSOR_KEY])
    camera["film"] = film()
    camera["sampler"] = {"type": "independent", "sample_count": 16}
    scene[SENSOR_KEY] = camera
    return scene


def cornell_glossy() -> SceneDict:
    """The Cornell box with rough metal and rough plastic walls and boxes.

    Roughness spans 0.05 (near-mirror, where caches struggle with sharp lobes)
    to 0.3; the ceiling stays diffuse so that the light still reaches the room
    through a broad first bounce.
    """
    scene = cornell_box()
    scene["white"] = rough_plastic((0.80, 0.78, 0.75), alpha=0.15)
    scene["red"] = rough_plastic((0.57, 0.043, 0.044), alpha=0.2)
    scene["green"] = rough_plastic((0.105, 0.378, 0.076), alpha=0.2)
    # Shapes refer to the materials by id ('white', 'red', 'green'); the
    # back wall, ceiling and boxes get their own so they can differ.
    scene["back"] = {**scene["back"], "bsdf": rough_conductor("Al", alpha=0.3)}
    scene["ceiling"] = {**scene["ceiling"], "bsdf": diffuse((0.80, 0.78, 0.75))}
    scene["large-box"] = {**scene["large-box"], "bsdf": rough_conductor("Au", alpha=0.1)}
    scene["small-box"] = {
        **scene["small-box"],
        "bsdf": rough_plastic((0.15, 0.25, 0.6), alpha=0.05),
    }
    return scene
