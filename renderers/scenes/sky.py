"""`sky`: a courtyard lit only by a procedural sky, for environment-map methods.

The environment map is generated here with numpy (no files): a sky gradient
from a pale horizon to a deep-blue zenith, a dim ground below the horizon and
a small, very bright sun blob with a soft halo. The courtyard's walls, an
arcade roof on pillars and a few objects occlude most of the sky from most
points, so env-map visibility (what `nvc-env` learns) varies a lot across the
image: sharp sun shadows, sky-lit shade and an arcade lit only indirectly.
"""

from __future__ import annotations

import numpy as np

from renderers.scenes.parts import (
    SceneDict,
    box_between,
    cylinder,
    diffuse,
    quad,
    rough_plastic,
    sensor,
    sphere,
)
from renderers.scenes.runtime import mitsuba

SKY_WIDTH, SKY_HEIGHT = 128, 64  # equirectangular env map resolution
SUN_ELEVATION_DEG = 40.0
SUN_AZIMUTH_DEG = 55.0  # measured from -z towards +x (the map's u = 0 direction)
SUN_SIGMA_DEG = 2.5  # angular spread of the sun blob
SUN_PEAK = 400.0  # radiance at the blob's centre: the sun gives ~1.4x the sky's irradiance


def _directions(width: int, height: int) -> np.ndarray:
    """World direction of each env-map pixel centre, shape (height, width, 3).

    Inverts Mitsuba's ``envmap`` lookup: u = atan2(x, -z) / 2pi,
    v = acos(y) / pi, so row 0 is the zenith.
    """
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    theta, phi = np.meshgrid(v * np.pi, u * 2 * np.pi, indexing="ij")
    return np.stack(
        [np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)], axis=-1
    )


def _unit_direction(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    e, a = np.radians(elevation_deg), np.radians(azimuth_deg)
    return np.array([np.cos(e) * np.sin(a), np.sin(e), -np.cos(e) * np.cos(a)])


def sky_radiance(width: int = SKY_WIDTH, height: int = SKY_HEIGHT) -> np.ndarray:
    """The sky env map as a float32 array of shape (height, width, 3), linear RGB."""
    d = _directions(width, height)
    up = d[..., 1:2]  # sine of the elevation

    horizon = np.array([0.95, 0.95, 1.00])
    zenith = np.array([0.22, 0.40, 0.95])
    ground = np.array([0.20, 0.18, 0.16])
    # A power < 1 keeps the pale band near the horizon narrow, as in real skies.
    sky = horizon + (zenith - horizon) * np.clip(up, 0.0, 1.0) ** 0.5
    # Blend into the ground over a few degrees: a hard step would alias.
    to_ground = np.clip(-up / 0.05, 0.0, 1.0)
    radiance = sky * (1 - to_ground) + ground * to_ground

    sun_dir = _unit_direction(SUN_ELEVATION_DEG, SUN_AZIMUTH_DEG)
    angle = np.arccos(np.clip(d @ sun_dir, -1.0, 1.0))[..., None]
    sun = SUN_PEAK * np.exp(-0.5 * (angle / np.radians(SUN_SIGMA_DEG)) ** 2)
    halo = 1.5 * np.exp(-0.5 * (angle / np.radians(12.0)) ** 2)
    radiance = radiance + (sun + halo) * np.array([1.0, 0.92, 0.8])
    return radiance.astype(np.float32)


def sky() -> SceneDict:
    """Courtyard + sky env map (see the module docstring)."""
    mi = mitsuba()
    stone = diffuse((0.62, 0.58, 0.52))
    plaster = diffuse((0.75, 0.70, 0.62))
    scene: SceneDict = {
        "type": "scene",
        "sky": {"type": "envmap", "bitmap": mi.Bitmap(sky_radiance())},
        "ground": quad((0, 0, 0), (0, 0, 20), (20, 0, 0), diffuse((0.45, 0.43, 0.40))),
    }

    # Enclosing buildings around the 10 m x 10 m yard, 4 m tall; the south
    # side (+z) has a 2.5 m gate so the yard is not a closed box.
    scene["building-north"] = box_between((-6, 0, -6), (6, 4.0, -5), plaster)
    scene["building-west"] = box_between((-6, 0, -5), (-5, 3.5, 5), plaster)
    scene["building-east"] = box_between((5, 0, -5), (6, 5.0, 5), plaster)
    scene["building-south-a"] = box_between((-6, 0, 5), (-1.0, 3.0, 6), plaster)
    scene["building-south-b"] = box_between((1.5, 0, 5), (6, 3.0, 6), plaster)

    # Arcade along the north side: a roof slab on pillars; beneath it only
    # light bounced off the yard arrives.
    scene["arcade-roof"] = box_between((-5, 2.6, -5), (5, 2.8, -3.2), stone)
    for i, x in enumerate(np.linspace(-4.2, 4.2, 5)):
        scene[f"pillar-{i}"] = cylinder((x, 0, -3.4), (x, 2.6, -3.4), 0.15, stone)

    # Objects in the yard: casters of sharp sun shadows and of sky occlusion.
    scene["fountain"] = sphere((-1.0, 0.8, 0.5), 0.8, rough_plastic((0.3, 0.5, 0.6), 0.2))
    scene["crate-a"] = box_between((2.0, 0, -1.5), (3.2, 1.2, -0.3), diffuse((0.55, 0.38, 0.2)))
    scene["crate-b"] = box_between((2.4, 1.2, -1.1), (3.0, 1.8, -0.5), diffuse((0.55, 0.38, 0.2)))
    scene["wall-low"] = box_between((-4.5, 0, 2.5), (-1.5, 1.0, 2.8), stone)

    scene["sensor"] = sensor(origin=(3.8, 2.0, 4.3), target=(-1.5, 1.0, -3.0), fov=70)
    return scene
