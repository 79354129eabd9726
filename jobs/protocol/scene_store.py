"""Scenes given over the REST API: vetted, then stored content-addressed in the data
folder, where the render loads them from.

A REST client names a scene in one of three ways (docs/service.md):

* a built-in name (``cornell-box``), used as is;
* ``upload:<digest>``, the id ``POST /api/v1/scenes`` answered with;
* the path of a Mitsuba XML file under a configured scene root
  (``NIRC_BENCH_SCENE_ROOTS``), absolute or relative to a root. It is vetted
  (renderers.scenes.vetting) and its files *copied* into the store at submission;
  the job's spec then names the copy, ``staged:<digest>``.

Both kinds of id name a folder ``<data_dir>/scenes/<digest>/`` holding the staged
``scene.xml`` and the files it reads. A folder is written under a temporary name
and renamed into place, and never changed afterwards: the same content always
gives the same id, and a render reads exactly the bytes that were vetted.

Anything else — a path outside the roots, a missing file, a symlink leading out —
gets one and the same message, :func:`unavailable_message`: the answer must not
tell a client whether some file exists on the server.

Stored scenes count in the data folder's size (jobs.execution.work.data_bytes), and
``nirc-bench gc`` removes those that no job, run, sweep, reference or cache snapshot
names (jobs/record/gc.py).
"""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
import sys
import tempfile
import threading
from pathlib import Path

from jobs.record.config import Settings
from renderers.backend import BackendError, default_variant, init_backend
from renderers.scenes import LoadedScene, SceneError, SceneFeatures, builtin_names, load_scene
from renderers.scenes.animated import animated_names
from renderers.scenes.errors import SceneNotFinite
from renderers.scenes.vetting import (
    STAGED_SCENE,
    Blob,
    SceneRefused,
    StagedScene,
    scene_limits,
    vet_root_scene,
    vet_upload,
)

#: ``upload:<digest>`` (sent by a client) or ``staged:<digest>`` (a scene-root file
#: copied at submission).
SCENE_ID = re.compile(r"^(upload|staged):([0-9a-f]{32})$")
#: The resolution a built-in scene is loaded at for its features: none of them but
#: ``resolution`` depends on it.
FEATURES_RESOLUTION = 8
#: The variant features are loaded with in a process that has chosen none (the
#: service's API process): the CPU's, so that no GPU context is opened for them —
#: unless the machine has no usable libLLVM but a GPU (:func:`features_backend`).
FEATURES_VARIANT = "llvm_ad_rgb"

_features: dict[str, SceneFeatures] = {}
_features_lock = threading.Lock()


def named_scenes() -> list[str]:
    """The scenes a job may name as they are: the built-in static and animated scenes
    (renderers.scenes.library, renderers.scenes.animated)."""
    return [*builtin_names(), *animated_names()]


def unavailable_message() -> str:
    """The one answer for a scene that does not exist *or* may not be used; it does
    not even repeat the name, so two answers can be compared byte for byte."""
    return ("the scene is not available: give a built-in scene "
            f"({', '.join(named_scenes())}), the id of an uploaded scene (upload:<digest>, "
            "from POST /api/v1/scenes) or the path of a Mitsuba XML file under the "
            "service's scene roots")


def stored_scene_file(scene: str, settings: Settings) -> Path | None:
    """The staged XML of a stored scene id, or None when ``scene`` is no such id (or
    names nothing stored)."""
    match = SCENE_ID.match(scene)
    if match is None:
        return None
    path = settings.scenes_dir / match.group(2) / STAGED_SCENE
    return path if path.is_file() else None


def store_scene(staged: StagedScene, settings: Settings) -> bool:
    """Write ``staged`` under its digest unless it is there; True if written now."""
    root = settings.scenes_dir
    target = root / staged.digest
    if is_stored(staged, settings):
        return False
    root.mkdir(parents=True, exist_ok=True)
    temporary = Path(tempfile.mkdtemp(prefix=".incoming-", dir=root))
    try:
        for name, data in staged.files.items():
            if isinstance(data, Path):
                shutil.copyfile(data, temporary / name)
            else:
                (temporary / name).write_bytes(data)
        try:
            os.rename(temporary, target)
        except OSError:
            # Another request stored the same content first (same digest, same bytes).
            if not (target / STAGED_SCENE).is_file():
                raise
            return False
        return True
    finally:
        shutil.rmtree(temporary, ignore_errors=True)


def save_upload(xml: bytes, files: dict[str, Blob], settings: Settings,
                room: int | None = None) -> tuple[str, StagedScene, bool]:
    """Vet and store an uploaded scene: its id, what was stored, and whether it was
    new. Raises SceneRefused (SceneTooLarge) for a scene that may not be stored, and
    :class:`NoRoom` for a new one larger than ``room`` (bytes left in the data
    folder's budget; None: no budget)."""
    staged = vet_upload(xml, files, scene_limits())
    if room is not None and staged.total_bytes > room and not is_stored(staged, settings):
        raise NoRoom(f"the scene is {staged.total_bytes / 1e6:.1f} MB and the data folder "
                     f"has {max(room, 0) / 1e6:.1f} MB left of this service's limit "
                     "(max_data_bytes); free space with `nirc-bench gc --apply`")
    created = store_scene(staged, settings)
    return f"upload:{staged.digest}", staged, created


class NoRoom(RuntimeError):
    """Storing this would take the data folder past its size limit."""


def is_stored(staged: StagedScene, settings: Settings) -> bool:
    return (settings.scenes_dir / staged.digest / STAGED_SCENE).is_file()


def rest_scene(scene: str, settings: Settings) -> str:
    """The scene a REST job renders, as its spec will name it: a built-in name, or
    the id of a stored copy. Raises SceneRefused with a message safe to serve."""
    if scene in named_scenes():
        return scene
    if SCENE_ID.match(scene):
        if stored_scene_file(scene, settings) is None:
            raise SceneRefused(unavailable_message())
        return scene
    staged = vet_root_scene(scene, settings.scene_roots, scene_limits(),
                            missing=unavailable_message())
    store_scene(staged, settings)
    return f"staged:{staged.digest}"


def features_backend() -> None:
    """Choose the variant scenes are loaded with for their features: the CPU's
    (:data:`FEATURES_VARIANT`), or, on a GPU machine without a usable libLLVM, the
    default variant (the GPU's), which would render the jobs anyway. Raises
    BackendError (naming what is missing) where neither can be used."""
    try:
        init_backend(FEATURES_VARIANT)
    except BackendError:
        if default_variant() == FEATURES_VARIANT:
            raise
        init_backend(default_variant())


def builtin_features(name: str) -> SceneFeatures:
    """The features of the built-in (static or animated) scene ``name`` (what decides
    which methods apply to it), loaded once per process: known without rendering anything, so that a job whose
    method does not apply can be refused before it is queued. Raises BackendError where
    no scene can be loaded (no usable libLLVM)."""
    with _features_lock:
        if name not in _features:
            mitsuba = sys.modules.get("mitsuba")
            if mitsuba is None or mitsuba.variant() is None:
                features_backend()
            _features[name] = load_scene(name, FEATURES_RESOLUTION).features
        return _features[name]


def load_spec_scene(scene: str, resolution: int, settings: Settings) -> LoadedScene:
    """Load the scene a job spec names: a stored id from the data folder, anything
    else through :func:`load_scene` (built-in names; local paths, which only the CLI
    passes — REST specs name stored ids).

    A stored scene that Mitsuba refuses fails with a fixed message naming the id:
    Mitsuba's own text can quote a line of a file, and a job's error is served to
    every reader. A scene refused for a non-finite value says which object, by its
    position and type (renderers.scenes.errors.SceneNotFinite).
    """
    if SCENE_ID.match(scene) is None:
        return load_scene(scene, resolution)
    path = stored_scene_file(scene, settings)
    if path is None:
        raise SceneError(unavailable_message())
    try:
        loaded = load_scene(path, resolution)
    except SceneNotFinite as err:
        # What is not finite, named by position and type only: safe to serve.
        raise SceneError(f"scene {scene} was refused: {err.reason}") from None
    except SceneError:
        raise SceneError(f"scene {scene} could not be loaded: Mitsuba refused the scene or "
                         "one of its files (its message is not shown, as it can quote the "
                         "files; `nirc-bench reference --scene FILE` on a copy shows it)") \
            from None
    # Its name in results is the id, not a path inside the service's data folder.
    return dataclasses.replace(loaded, name=scene)
