"""The built-in animated scenes: a built-in scene and an animation of it
(renderers.scenes.animation; docs/animation.md lists what each shows).

They are separate from the static built-ins (renderers.scenes.library): a static
scene's name, fingerprint and the studies that loop over the built-ins stay as
they were. An animated scene's fingerprint is its base scene's joined with its
animation's digest.
"""

from __future__ import annotations

from dataclasses import dataclass

from renderers.scenes.animation import Animation, CameraKey, EmitterChange, ShapeKey, ShapeMotion
from renderers.scenes.door import DOOR_X0, WALL_Z
from renderers.scenes.errors import SceneError

#: The frame of the sudden scenes' change (8 frames before it to settle a cache).
SUDDEN_FRAME = 8


@dataclass(frozen=True)
class AnimatedScene:
    name: str
    base: str                # a built-in scene's name
    description: str
    animation: Animation


_DOOR_PIVOT = (DOOR_X0, 0.0, WALL_Z - 0.02)   # the door's hinge (door.py: 0.04 thick)

_SCENES = (
    AnimatedScene(
        "door-pan", "door",
        "door: the camera pans across the room over frames 0-15 (continuous motion)",
        Animation(camera=[
            CameraKey(frame=0, position=(-1.7, 1.6, 1.8), target=(0.6, 0.6, -1.5), fov=70.0),
            CameraKey(frame=15, position=(1.6, 1.6, 1.8), target=(-0.4, 0.7, -1.5), fov=70.0),
        ])),
    AnimatedScene(
        "cornell-box-moving", "cornell-box",
        "cornell-box: the small box slides forward and turns 45 degrees over frames 0-8",
        Animation(shapes=[ShapeMotion(
            shape="small-box", pivot=(0.335, -0.7, 0.38),
            keys=[ShapeKey(frame=0), ShapeKey(frame=8, translate=(-0.25, 0.0, 0.2),
                                              angle_deg=45.0)])])),
    AnimatedScene(
        "many-lights-switch", "many-lights",
        "many-lights: 8 of the 32 lights switch off at frame 6 and on again at frame 12",
        Animation(emitters=[EmitterChange(emitter=f"light-{index:02d}", frame=frame, scale=scale)
                            for index in range(8) for frame, scale in ((6, 0.0), (12, 1.0))])),
    AnimatedScene(
        "cornell-box-sudden", "cornell-box",
        f"cornell-box: the ceiling light jumps to 4x its radiance at frame {SUDDEN_FRAME}",
        Animation(emitters=[EmitterChange(emitter="light", frame=SUDDEN_FRAME, scale=4.0)])),
    AnimatedScene(
        "door-sudden", "door",
        f"door: the door swings wide open (15 to 80 degrees) at frame {SUDDEN_FRAME}",
        Animation(shapes=[ShapeMotion(
            shape="door", pivot=_DOOR_PIVOT,
            keys=[ShapeKey(frame=0), ShapeKey(frame=SUDDEN_FRAME, angle_deg=65.0, step=True)])])),
)

ANIMATED: dict[str, AnimatedScene] = {scene.name: scene for scene in _SCENES}


def animated_names() -> list[str]:
    """Names of the built-in animated scenes, in their documentation order."""
    return list(ANIMATED)


def get_animated(name: str) -> AnimatedScene:
    try:
        return ANIMATED[name]
    except KeyError:
        raise SceneError(f"unknown animated scene '{name}' ({', '.join(ANIMATED)})") from None
