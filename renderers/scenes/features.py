"""Scene features: what a scene contains, computed once when it is loaded.

Features decide what the benchmark runs and what it skips with a stated
reason (e.g. the env-map visibility cache on a scene without an env map), and
they are stored with every result. They are read from the loaded ``mi.Scene``
itself, so XML scenes and built-ins are described the same way.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from renderers.scenes.runtime import mitsuba

#: From this many finite (non-environment) emitters on, light selection is a
#: problem worth a method of its own (`nvc-lights`); below it, NEE's uniform
#: choice is already good. A heuristic, stated here so it is visible.
MANY_LIGHTS_MIN = 8
#: The parts of a scene an animation can change (renderers.scenes.animation).
ANIMATED_PARTS = ("camera", "shapes", "emitters")


@dataclass(frozen=True)
class SceneFeatures:
    """JSON-ready description of a loaded scene (``dataclasses.asdict`` works)."""

    resolution: tuple[int, int]  # film (width, height) the scene was loaded with
    shape_count: int
    emitter_count: int  # all emitters, environment included
    area_emitter_count: int  # emitters attached to surfaces
    has_envmap: bool  # an infinite, non-delta emitter (envmap, constant, ...)
    has_many_lights: bool  # >= MANY_LIGHTS_MIN finite emitters
    has_glossy: bool  # some BSDF has a glossy component
    has_delta: bool  # some BSDF has a delta (or null) component
    bbox_min: list[float]  # scene bounding box (shapes only)
    bbox_max: list[float]
    polygon_emitter_count: int = 0  # area emitters on meshes (rectangles, triangle meshes)
    #: What an animation of the scene changes from frame to frame, of ANIMATED_PARTS
    #: (renderers.scenes.loader.animated); empty for a static scene.
    animation_changes: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["resolution"] = list(self.resolution)
        if self.animation_changes:
            data["animation_changes"] = list(self.animation_changes)
        else:   # a static scene's features are stored as they were before animations
            del data["animation_changes"]
        return data


def _bsdf_flags(scene: Any) -> int:
    """Union of the flags of every shape's BSDF (components included)."""
    flags = 0
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if bsdf is not None:
            flags |= int(bsdf.flags())
    return flags


def compute_features(scene: Any, resolution: tuple[int, int]) -> SceneFeatures:
    """Describe a loaded ``mi.Scene`` rendered at ``resolution``."""
    mi = mitsuba()
    emitters = scene.emitters()
    # `is_environment()` is Mitsuba's own test: infinite and not delta, i.e.
    # envmap/constant/sunsky but not a directional light.
    environment = [e for e in emitters if e.is_environment()]
    area = [e for e in emitters if int(e.flags()) & int(mi.EmitterFlags.Surface)]
    polygons = [e for e in area if e.get_shape() is not None and e.get_shape().is_mesh()]
    flags = _bsdf_flags(scene)
    bbox = scene.bbox()
    # A scene of only an env map has an empty (infinite) box; JSON has no inf.
    lo, hi = (bbox.min, bbox.max) if bbox.valid() else ((0.0,) * 3, (0.0,) * 3)
    return SceneFeatures(
        resolution=(int(resolution[0]), int(resolution[1])),
        shape_count=len(scene.shapes()),
        emitter_count=len(emitters),
        area_emitter_count=len(area),
        has_envmap=bool(environment),
        has_many_lights=len(emitters) - len(environment) >= MANY_LIGHTS_MIN,
        has_glossy=bool(flags & int(mi.BSDFFlags.Glossy)),
        has_delta=bool(flags & int(mi.BSDFFlags.Delta)),
        bbox_min=[float(x) for x in lo],
        bbox_max=[float(x) for x in hi],
        polygon_emitter_count=len(polygons),
    )
