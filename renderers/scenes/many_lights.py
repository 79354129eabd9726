"""`many-lights`: an open-plan room with 32 small ceiling lights and partitions.

Partition walls (lower than the ceiling, with gaps to walk through) split the
room into eight bays with four small coloured lights each. From any point on
the floor most of the 32 lights are hidden behind partitions, while the
ceiling sees them all: per-light visibility varies strongly and smoothly over
the scene, which is what the per-light visibility cache (`nvc-lights`) and
light-selection methods are meant to exploit. 32 is the most lights one
visibility cache output layer handles without clustering.
"""

from __future__ import annotations

import numpy as np

from renderers.scenes.parts import (
    SceneDict,
    area_light,
    box_between,
    diffuse,
    quad,
    room,
    sensor,
    two_sided,
)

HALF = 4.0  # the room spans x, z in [-HALF, HALF]
HEIGHT = 3.0
PARTITION_HEIGHT = 2.0
PARTITION_THICKNESS = 0.08
LIGHT_HALF = 0.12  # lights are 0.24 m squares
LIGHT_COUNT = 32
LIGHT_SEED = 7  # fixed: the colours are part of the scene definition


def _light_colours(count: int) -> np.ndarray:
    """Distinct, deterministic warm-to-cool tints of similar power."""
    rng = np.random.default_rng(LIGHT_SEED)
    tint = rng.uniform(0.35, 1.0, size=(count, 3))
    power = rng.uniform(0.6, 1.4, size=(count, 1))
    # Normalise by the mean channel so that every light has a similar power.
    return 20.0 * power * tint / tint.mean(axis=1, keepdims=True)


def partitions(bsdf: SceneDict) -> dict[str, SceneDict]:
    t, h = PARTITION_THICKNESS / 2, PARTITION_HEIGHT
    shapes: dict[str, SceneDict] = {}
    # Three long partitions across z (at x = -2, 0, 2) with a gap at each end.
    for i, x in enumerate((-2.0, 0.0, 2.0)):
        shapes[f"partition-x{i}"] = box_between((x - t, 0, -3.0), (x + t, h, 3.0), bsdf)
    # One partition along x at z = 0, cut into pieces with doorways between bays.
    for i, (x0, x1) in enumerate(((-4.0, -2.8), (-1.2, 0.8), (2.4, 4.0))):
        shapes[f"partition-z{i}"] = box_between((x0, 0, -t), (x1, h, t), bsdf)
    return shapes


def office() -> SceneDict:
    """The open-plan room and its partitions, without lights or furniture (the start of
    `many-lights` and `many-lights-300`)."""
    wall = two_sided(diffuse((0.7, 0.7, 0.7)))
    scene: SceneDict = {"type": "scene"}
    scene.update(room((-HALF, 0, -HALF), (HALF, HEIGHT, HALF), wall))
    scene["floor"]["bsdf"] = two_sided(diffuse((0.5, 0.45, 0.4)))
    scene.update(partitions(two_sided(diffuse((0.55, 0.6, 0.7)))))
    return scene


def furnish(scene: SceneDict) -> SceneDict:
    """Add the desks (more occluders, surfaces at a second height) and the default view."""
    desk = diffuse((0.45, 0.3, 0.2))
    scene["desk-0"] = box_between((-3.6, 0, -3.5), (-2.4, 0.75, -2.7), desk)
    scene["desk-1"] = box_between((0.4, 0, 1.0), (1.6, 0.75, 1.8), desk)
    scene["desk-2"] = box_between((2.4, 0, -2.5), (3.6, 0.75, -1.7), desk)
    scene["sensor"] = sensor(origin=(3.7, 2.7, 3.7), target=(-1.0, 0.2, -1.0), fov=75)
    return scene


def many_lights() -> SceneDict:
    """The room, partitions, some furniture and the 32 lights."""
    scene = office()

    # Four lights per bay; bays are 2 m (x) by 4 m (z).
    colours = _light_colours(LIGHT_COUNT)
    index = 0
    for bay_x in (-3.0, -1.0, 1.0, 3.0):
        for bay_z in (-2.0, 2.0):
            for dx, dz in ((-0.5, -1.0), (0.5, -1.0), (-0.5, 1.0), (0.5, 1.0)):
                # Facing down (u x v = -y), just below the ceiling.
                scene[f"light-{index:02d}"] = quad(
                    (bay_x + dx, HEIGHT - 0.01, bay_z + dz),
                    (LIGHT_HALF, 0, 0),
                    (0, 0, LIGHT_HALF),
                    emitter=area_light(colours[index]),
                )
                index += 1
    return furnish(scene)


def floor_view() -> SceneDict:
    """The same room seen from below the lights, looking down at the floor and desks: no
    light in view, so the error of a 1-spp frame is light sampling's (in the default view
    a pixel that partly covers a light dominates it). Used by tests/renderers/test_restir.py
    and benchmarks/bench_restir.py; not a built-in scene."""
    scene = many_lights()
    scene["sensor"] = sensor(origin=(3.5, 1.6, 3.5), target=(-1.0, -1.4, -1.0), fov=45)
    return scene
