"""`door`: a room lit only through the gap of a door left ajar (after Veach's door).

The only light is a bright panel on the far wall of an adjacent room; the
camera's room receives light only through the narrow wedge between the door
(swung slightly into the light room) and its frame: a sliver of direct light
on the floor, everything else bounced. Nearly everything the camera sees is
indirect light of two or more bounces, and most paths from the camera never
find the gap: the case where path tracing is noisy and a radiance cache can
pay off.
"""

from __future__ import annotations

from renderers.scenes.parts import (
    SceneDict,
    area_light,
    box,
    box_between,
    diffuse,
    quad,
    room,
    sensor,
    sphere,
    two_sided,
)
from renderers.scenes.runtime import mitsuba

# Camera room: x in [-2, 2], y in [0, 2.6], z in [-2, 2]; the door wall is z = -2.
ROOM_LO, ROOM_HI = (-2.0, 0.0, -2.0), (2.0, 2.6, 2.0)
# Light room behind it: z in [-4.5, -2].
LIGHT_ROOM_LO, LIGHT_ROOM_HI = (-2.0, 0.0, -4.5), (2.0, 2.6, -2.0)
# Door opening in the wall z = -2 (x from DOOR_X0 to DOOR_X1, y up to DOOR_TOP).
DOOR_X0, DOOR_X1, DOOR_TOP = 0.2, 1.2, 2.0
DOOR_OPEN_DEG = 15.0  # how far the door swings into the light room
WALL_Z = -2.0


def _door_wall(bsdf: SceneDict) -> dict[str, SceneDict]:
    """The wall between the rooms, as three quads around the door opening."""
    x0, x1, top = DOOR_X0, DOOR_X1, DOOR_TOP
    (lx, _, _), (hx, hy, _) = ROOM_LO, ROOM_HI
    # Centre and half-extents of each piece; two-sided so it bounces light on
    # both the light-room side and the camera side.
    pieces = {
        "door-wall-left": ((lx + x0) / 2, hy / 2, (x0 - lx) / 2, hy / 2),
        "door-wall-right": ((x1 + hx) / 2, hy / 2, (hx - x1) / 2, hy / 2),
        "door-wall-top": ((x0 + x1) / 2, (top + hy) / 2, (x1 - x0) / 2, (hy - top) / 2),
    }
    return {
        name: quad((cx, cy, WALL_Z), (sx, 0, 0), (0, sy, 0), bsdf)
        for name, (cx, cy, sx, sy) in pieces.items()
    }


def door() -> SceneDict:
    """Camera room + door ajar + light room (see the module docstring)."""
    wall = two_sided(diffuse((0.8, 0.78, 0.74)))
    floor = two_sided(diffuse((0.45, 0.35, 0.25)))
    # Both rooms leave out their side of the shared wall, built with the opening.
    camera_room = room(ROOM_LO, ROOM_HI, wall, skip=("wall-z0",))
    light_room = room(LIGHT_ROOM_LO, LIGHT_ROOM_HI, wall, skip=("wall-z1",))
    camera_room["floor"]["bsdf"] = floor
    scene: SceneDict = {"type": "scene"}
    scene.update({f"room-{key}": shape for key, shape in camera_room.items()})
    scene.update({f"light-room-{key}": shape for key, shape in light_room.items()})
    scene.update(_door_wall(wall))

    # The door: a slab hinged at x = DOOR_X0, swung DOOR_OPEN_DEG into the
    # light room (a positive turn about +y moves its free edge towards -z).
    width, height, thickness = DOOR_X1 - DOOR_X0, DOOR_TOP - 0.02, 0.04
    scene["door"] = {
        "type": "cube",
        "to_world": mitsuba()
        .ScalarTransform4f()
        .translate([DOOR_X0, height / 2, WALL_Z - thickness / 2])
        .rotate([0.0, 1.0, 0.0], DOOR_OPEN_DEG)
        .translate([width / 2, 0.0, 0.0])
        .scale([width / 2, height / 2, thickness / 2]),
        "bsdf": diffuse((0.35, 0.22, 0.12)),
    }

    # The only light: a panel high on the light room's far wall, facing the
    # door, so that a sliver of direct light falls through the gap onto the
    # camera room's floor while the rest of the room sees only bounced light.
    scene["light"] = quad(
        (1.2, 1.9, -4.49), (0.6, 0, 0), (0, 0.45, 0), emitter=area_light((250.0, 210.0, 160.0))
    )

    # Furniture in the camera room, to give the indirect light something to shade.
    scene["table"] = box_between((-1.3, 0.0, -0.9), (-0.3, 0.75, 0.1), diffuse((0.55, 0.4, 0.3)))
    scene["cabinet"] = box((1.5, 0.6, 0.4), (0.35, 0.6, 0.5), diffuse((0.3, 0.45, 0.6)), yaw=10)
    scene["ball"] = sphere((-0.8, 1.0, -0.4), 0.25, diffuse((0.8, 0.8, 0.8)))

    scene["sensor"] = sensor(origin=(-1.7, 1.6, 1.8), target=(0.6, 0.6, -1.5), fov=70)
    return scene
