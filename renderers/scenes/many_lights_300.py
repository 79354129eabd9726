"""`many-lights-300`: the `many-lights` room with 300 small lights of varied power.

The open-plan room of `many-lights` (eight bays behind partitions, desks), lit
by 240 small ceiling lights on a jittered 20 x 12 grid and 60 tiny up-facing
floor lamps (10 per column of bays, lighting the ceiling and the partitions
from below). Powers are log-uniform over two decades and the tints vary, so
power-proportional selection alone is a poor guide; from any point on the floor
most lights are hidden behind partitions. 300 lights is beyond one visibility
cache output per light (32): the scene exercises the clustered neural visibility
cache (`nvc-lights` with clusters) and light selection at hundreds of emitters.
Geometry stays small (the room, six partition boxes, three desks and 300
quads), so it renders as cheaply as `many-lights`.
"""

from __future__ import annotations

import numpy as np

from renderers.scenes.many_lights import HALF, HEIGHT, furnish, office
from renderers.scenes.parts import (
    SceneDict,
    area_light,
    quad,
)

CEILING_GRID = (20, 12)   # lights along x, z
FLOOR_LAMPS = 60
CEILING_HALF = 0.06       # ceiling lights are 0.12 m squares
LAMP_HALF = 0.03          # floor lamps are 0.06 m squares
LIGHT_SEED = 300          # fixed: positions, powers and tints are part of the scene


def _radiances(rng: np.random.Generator, count: int, scale: float) -> np.ndarray:
    """Tinted radiances whose power is log-uniform over two decades."""
    tint = rng.uniform(0.35, 1.0, size=(count, 3))
    power = 10.0 ** rng.uniform(-1.0, 1.0, size=(count, 1))
    return scale * power * tint / tint.mean(axis=1, keepdims=True)


def many_lights_300() -> SceneDict:
    """The room, partitions, desks, 240 ceiling lights and 60 floor lamps."""
    rng = np.random.default_rng(LIGHT_SEED)
    scene = office()

    nx, nz = CEILING_GRID
    ceiling = _radiances(rng, nx * nz, 40.0)
    step = 2 * HALF / np.array([nx, nz])
    index = 0
    for i in range(nx):
        for k in range(nz):
            jitter = rng.uniform(-0.25, 0.25, size=2) * step
            x, z = -HALF + (np.array([i, k]) + 0.5) * step + jitter
            scene[f"light-{index:03d}"] = quad(  # facing down (u x v = -y)
                (x, HEIGHT - 0.01, z), (CEILING_HALF, 0, 0), (0, 0, CEILING_HALF),
                emitter=area_light(ceiling[index]))
            index += 1
    lamps = _radiances(rng, FLOOR_LAMPS, 150.0)
    for j in range(FLOOR_LAMPS):
        x, z = rng.uniform(-HALF + 0.2, HALF - 0.2, size=2)
        scene[f"light-{index:03d}"] = quad(  # facing up (u x v = +y)
            (x, 0.01, z), (0, 0, LAMP_HALF), (LAMP_HALF, 0, 0),
            emitter=area_light(lamps[j]))
        index += 1
    return furnish(scene)
