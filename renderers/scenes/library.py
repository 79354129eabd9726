"""The registry of built-in procedural scenes: name -> builder and description.

A builder returns a fresh ``mi.load_dict`` dictionary *without* film
resolution. Changing what any builder produces changes that scene's
fingerprint automatically (the dictionary is hashed); bump
:data:`LIBRARY_VERSION` only when the *meaning* of a definition changes
without the dictionary changing (e.g. a different canonicalisation).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from renderers.scenes.cornell import cornell_box, cornell_glossy
from renderers.scenes.corridor import corridor
from renderers.scenes.door import door
from renderers.scenes.errors import SceneError
from renderers.scenes.many_lights import many_lights
from renderers.scenes.many_lights_300 import many_lights_300
from renderers.scenes.parts import SceneDict
from renderers.scenes.sky import sky
from renderers.scenes.white_room import white_room

#: Mixed into every built-in fingerprint (see the module docstring).
LIBRARY_VERSION = 1


@dataclass(frozen=True)
class BuiltinScene:
    name: str
    description: str
    build: Callable[[], SceneDict]


_SCENES = (
    BuiltinScene(
        "cornell-box",
        "Mitsuba's diffuse Cornell box: one small ceiling light, direct and indirect light",
        cornell_box,
    ),
    BuiltinScene(
        "cornell-glossy",
        "Cornell box with rough metal and rough plastic walls and boxes (roughness 0.05-0.3)",
        cornell_glossy,
    ),
    BuiltinScene(
        "door",
        "room lit only through the gap of a door ajar from a bright light next door "
        "(indirect dominated, after Veach's door)",
        door,
    ),
    BuiltinScene(
        "corridor",
        "winding corridor whose only light is two corners away (reachable after several bounces)",
        corridor,
    ),
    BuiltinScene(
        "sky",
        "courtyard with arcade and occluders lit only by a procedural sky env map with a sun",
        sky,
    ),
    BuiltinScene(
        "many-lights",
        "open-plan room with 32 small coloured ceiling lights hidden behind partitions",
        many_lights,
    ),
    BuiltinScene(
        "many-lights-300",
        "the many-lights room with 300 small lights of varied power (beyond one cache "
        "output per light)",
        many_lights_300,
    ),
    BuiltinScene(
        "white-room",
        "bright white interior lit indirectly by two hidden up-lights (high albedo, long paths)",
        white_room,
    ),
)

BUILTINS: dict[str, BuiltinScene] = {scene.name: scene for scene in _SCENES}


def builtin_names() -> list[str]:
    """Names of the built-in scenes, in their canonical (documentation) order."""
    return list(BUILTINS)


def get_builtin(name: str) -> BuiltinScene:
    try:
        return BUILTINS[name]
    except KeyError:
        raise SceneError(
            f"unknown scene '{name}': not a built-in ({', '.join(BUILTINS)}) "
            "and not a path to a Mitsuba .xml file"
        ) from None


def describe(name: str) -> str:
    """One-line human description of a built-in scene."""
    return get_builtin(name).description
