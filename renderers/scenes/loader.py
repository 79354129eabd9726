"""`load_scene`: one entry point for built-in names and XML paths.

Scenes are loaded with Mitsuba's ``optimize=False``. Its default merges
shapes that share a BSDF, and then (measured with Mitsuba 3.9.1) the order of
``scene.emitters()`` changes from one load to the next — so the same seed
would not give the same image, and per-light caches could not index lights —
and ``scene.bbox()`` leaves the merged meshes out. Rendering speed was the
same either way on the built-ins.

A :class:`LoadedScene` bundles the ``mi.Scene`` with everything the rest of
the service keys and reports on: its fingerprint (references and results are
stored under it), its features (which methods apply) and its resolution.
"""

from __future__ import annotations

import dataclasses
import os
import stat
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from renderers.scenes.animated import ANIMATED, get_animated
from renderers.scenes.animation import Animation, AnimationPlayer
from renderers.scenes.errors import SceneError
from renderers.scenes.features import ANIMATED_PARTS, SceneFeatures, compute_features
from renderers.scenes.fingerprint import _referenced_names as referenced_names
from renderers.scenes.fingerprint import builtin_fingerprint
from renderers.scenes.library import BUILTINS, LIBRARY_VERSION, get_builtin
from renderers.scenes.parts import set_film_resolution
from renderers.scenes.resolution import DEFAULT_RESOLUTION, Resolution, normalize_resolution
from renderers.scenes.runtime import mitsuba
from renderers.scenes.vetting import MAX_FILE_BYTES_VARIABLE, scene_limits
from renderers.scenes.xml_scene import is_scene_file, load_xml_scene
from renderers.seeding import digest


@dataclass
class LoadedScene:
    """A scene ready to render, with its identity and features."""

    name: str  # built-in name, or the XML file's absolute path
    source: Literal["builtin", "xml"]
    scene: Any  # mi.Scene
    fingerprint: str  # content hash, independent of resolution
    features: SceneFeatures
    resolution: Resolution  # (width, height) of the film
    description: str  # one line for humans
    #: What an XML file sets that a run replaces (renderers.scenes.xml_settings): film
    #: size before the resolution override, integrator, its max_depth, sampler spp.
    file_settings: dict[str, Any] = field(default_factory=dict)
    #: Its animation (renderers.scenes.animation), None for a static scene, and the one
    #: player that applies it: a player keeps the parameters' values as loaded, so a
    #: second one made after frames were shown would move from the moved pose.
    animation: Animation | None = None
    player: AnimationPlayer | None = None

    def to_json(self) -> dict[str, Any]:
        """Everything but the ``mi.Scene``, as JSON-ready values."""
        data = {
            "name": self.name,
            "source": self.source,
            "fingerprint": self.fingerprint,
            "features": self.features.to_json(),
            "resolution": list(self.resolution),
            "description": self.description,
        }
        if self.animation is not None:
            data["animation"] = self.animation.model_dump(mode="json")
        return data


def animated(loaded: LoadedScene, animation: Animation, name: str | None = None,
             description: str | None = None) -> LoadedScene:
    """``loaded`` with ``animation``: its fingerprint joined with the animation's digest,
    every name the animation uses checked against the scene (SceneError), frame 0 shown."""
    if loaded.animation is not None:
        raise SceneError(f"scene '{loaded.name}' is animated already: give an animation "
                         "only with a static scene")
    player = AnimationPlayer(loaded.scene, animation)
    player.apply(0)
    changes = tuple(part for part in ANIMATED_PARTS if getattr(animation, part))
    return dataclasses.replace(
        loaded, name=name or loaded.name, animation=animation, player=player,
        features=dataclasses.replace(loaded.features, animation_changes=changes),
        fingerprint=digest("animated-scene", loaded.fingerprint, animation.digest()),
        description=description or f"{loaded.description}, animated")


def _load_builtin(name: str, resolution: Resolution | None) -> LoadedScene:
    builtin = get_builtin(name)
    definition = builtin.build()
    # Hash before the film size is written in: the fingerprint must not see it.
    fingerprint = builtin_fingerprint(definition, LIBRARY_VERSION)
    width, height = resolution or DEFAULT_RESOLUTION
    scene = mitsuba().load_dict(
        set_film_resolution(definition, width, height), optimize=False
    )
    return LoadedScene(
        name=name,
        source="builtin",
        scene=scene,
        fingerprint=fingerprint,
        features=compute_features(scene, (width, height)),
        resolution=(width, height),
        description=builtin.description,
    )


def _checked_file(path: Path, what: str, cap: int) -> bool:
    """Whether ``path`` exists; refuses (SceneError) anything but a regular file of at
    most ``cap`` bytes: opening a FIFO or a device would block the render forever."""
    try:
        info = path.stat()
    except (OSError, ValueError):
        return False
    if not stat.S_ISREG(info.st_mode):
        raise SceneError(f"{what} {path}: not a regular file (a FIFO, device, socket or "
                         "folder); scenes and the files they use must be regular files")
    if info.st_size > cap:
        raise SceneError(f"{what} {path}: {info.st_size} bytes, more than the {cap} this "
                         f"service accepts ({MAX_FILE_BYTES_VARIABLE})")
    return True


def check_scene_files(xml_path: Path, seen: set[Path] | None = None) -> None:
    """Before anything opens them: the XML at ``xml_path``, its includes and every file
    it names (``filename``) wherever Mitsuba would look (absolute, beside the XML, the
    working folder) are regular files within the scenes' size limit (each file at most
    :func:`renderers.scenes.vetting.scene_limits`' ``max_file_bytes``)."""
    seen = set() if seen is None else seen
    cap = scene_limits().max_file_bytes
    if not _checked_file(xml_path, "scene file", cap):
        return                  # missing: load_xml_scene explains
    seen.add(xml_path.resolve())
    try:
        root = ET.fromstring(xml_path.read_bytes())
    except ET.ParseError:
        return                  # malformed: load_xml_scene explains, with the position
    for name in referenced_names(root):
        relative = Path(name)
        for candidate in ((relative,) if relative.is_absolute()
                          else (xml_path.parent / relative, Path.cwd() / relative)):
            is_xml = candidate.suffix.lower() == ".xml"
            if _checked_file(candidate, "file used by the scene", cap) and is_xml \
                    and candidate.resolve() not in seen:
                check_scene_files(candidate, seen)


def _load_xml(path: str, resolution: Resolution | None) -> LoadedScene:
    if is_scene_file(path):     # else load_xml_scene says why it cannot be read
        check_scene_files(Path(path).expanduser())
    loaded = load_xml_scene(path, resolution)
    features = compute_features(loaded.scene, loaded.resolution)
    return LoadedScene(
        name=str(loaded.path),
        source="xml",
        scene=loaded.scene,
        fingerprint=loaded.fingerprint,
        features=features,
        resolution=loaded.resolution,
        description=(
            f"Mitsuba XML scene {loaded.path.name} ({features.shape_count} shapes, "
            f"{features.emitter_count} emitters)"
        ),
        file_settings=loaded.settings,
    )


def load_scene(
    name_or_path: str | os.PathLike[str], resolution: int | tuple[int, int] | None = None
) -> LoadedScene:
    """Load a built-in scene by name or a Mitsuba XML scene by path.

    ``resolution`` is an int (square) or ``(width, height)``, each 1..8192.
    ``None`` keeps the scene's own: 256x256 for built-ins, the film's size
    for XML. Raises SceneError, with a one-line message, for anything wrong.
    """
    name = os.fspath(name_or_path)
    size = normalize_resolution(resolution)
    if name not in BUILTINS and Path(name).suffix.lower() == ".xml":
        return _load_xml(name, size)
    if name in ANIMATED:
        scene = get_animated(name)
        return animated(_load_builtin(scene.base, size), scene.animation, scene.name,
                        scene.description)
    # Unknown names fail here with the list of built-ins.
    return _load_builtin(name, size)
