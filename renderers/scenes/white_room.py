"""`white-room`: a bright interior lit indirectly, with high-albedo walls.

Light strips hidden on ledges along the side walls (cove lighting) shine at
the ceiling; everything the camera sees is lit by light that has bounced at
least once, and because walls, ceiling and furniture reflect 85 % the
radiance keeps a large share of its energy over many bounces. Long paths matter here (truncating at a few
bounces visibly darkens the image), which is where radiance caches promise
the most.
"""

from __future__ import annotations

from renderers.scenes.parts import (
    SceneDict,
    area_light,
    box_between,
    diffuse,
    quad,
    room,
    sensor,
    sphere,
    two_sided,
)

ROOM_LO, ROOM_HI = (-3.0, 0.0, -2.5), (3.0, 3.0, 2.5)
WHITE = (0.85, 0.85, 0.85)
LEDGE_Y = 2.3  # height of the cove ledges (the camera is below it)
LEDGE_DEPTH = 0.35


def white_room() -> SceneDict:
    """The room, its white furniture and the two cove lights."""
    white = two_sided(diffuse(WHITE))
    scene: SceneDict = {"type": "scene"}
    scene.update(room(ROOM_LO, ROOM_HI, white))
    scene["floor"]["bsdf"] = two_sided(diffuse((0.8, 0.76, 0.7)))

    # Cove lighting: a ledge along each side wall, above eye height, with a
    # light strip on top facing the ceiling. The camera never sees a light;
    # the ceiling is lit first and everything else by what it reflects.
    (x0, _, z0), (x1, _, z1) = ROOM_LO, ROOM_HI
    half_length = (z1 - z0) / 2 - 0.1
    for name, x, inward in (("left", x0, 1.0), ("right", x1, -1.0)):
        scene[f"ledge-{name}"] = box_between(
            (min(x, x + inward * LEDGE_DEPTH), LEDGE_Y - 0.08, z0),
            (max(x, x + inward * LEDGE_DEPTH), LEDGE_Y, z1),
            white,
        )
        scene[f"cove-light-{name}"] = quad(
            (x + inward * LEDGE_DEPTH / 2, LEDGE_Y + 0.005, (z0 + z1) / 2),
            (0, 0, half_length),
            (LEDGE_DEPTH / 2 - 0.05, 0, 0),  # u x v = +y: emits towards the ceiling
            emitter=area_light((10.0, 9.0, 7.6)),
        )

    # A tall cabinet against the back wall.
    scene["cabinet"] = box_between((1.2, 0, -2.5), (2.4, 2.0, -1.9), white)

    # Furniture in (near) white: shape comes almost only from shading.
    sofa = two_sided(diffuse((0.78, 0.74, 0.68)))
    scene["sofa-seat"] = box_between((-1.6, 0, 0.6), (0.6, 0.45, 1.5), sofa)
    scene["sofa-back"] = box_between((-1.6, 0.45, 1.3), (0.6, 1.0, 1.5), sofa)
    scene["table"] = box_between((-0.9, 0, -0.7), (0.3, 0.5, 0.1), white)
    scene["ball"] = sphere((1.5, 0.35, 0.0), 0.35, white)

    scene["sensor"] = sensor(origin=(2.4, 1.6, 2.3), target=(-0.8, 1.0, -1.5), fov=70)
    return scene
