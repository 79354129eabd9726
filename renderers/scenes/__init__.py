"""The scene library: built-in procedural scenes and Mitsuba XML scenes by path.

Public API::

    load_scene(name_or_path, resolution=None) -> LoadedScene
    builtin_names() -> list[str]
    describe(name) -> str
    SceneError, LoadedScene, SceneFeatures

Built-ins (``cornell-box``, ``cornell-glossy``, ``door``, ``corridor``,
``sky``, ``many-lights``, ``many-lights-300``, ``white-room``) are generated in Python — no files,
no downloads — and carry no integrator: the renderer under test passes its
own. Every loaded scene has a resolution-independent fingerprint and features
computed once at load time. See docs/design.md, section "Scenes".
"""

from __future__ import annotations

from renderers.scenes.errors import SceneError
from renderers.scenes.features import SceneFeatures
from renderers.scenes.library import LIBRARY_VERSION, builtin_names, describe
from renderers.scenes.loader import LoadedScene, load_scene
from renderers.scenes.xml_scene import is_scene_file

__all__ = [
    "LIBRARY_VERSION",
    "LoadedScene",
    "SceneError",
    "SceneFeatures",
    "builtin_names",
    "describe",
    "is_scene_file",
    "load_scene",
]
