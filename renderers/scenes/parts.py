"""Building blocks for the procedural scenes: camera, materials, shapes, rooms.

Every built-in scene is a plain ``mi.load_dict`` dictionary assembled from these
helpers, so that the dictionary *is* the scene definition: it is what gets
fingerprinted (see ``fingerprint.py``) and what gets loaded. Helpers return
fresh dictionaries; callers may mutate them freely.

Conventions: +y is up, lengths are in metres, colours are linear RGB.
The camera's film carries no width/height here — the loader writes the
resolution in last (:func:`set_film_resolution`), which keeps the definition,
and therefore the fingerprint, independent of resolution.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from renderers.scenes.runtime import mitsuba

SceneDict = dict[str, Any]
Vec3 = Sequence[float]
RGB = Sequence[float]

#: Key of the camera in every built-in scene dictionary.
SENSOR_KEY = "sensor"


# ---- Camera ----------------------------------------------------------------

def film() -> SceneDict:
    """An RGB float film with a box filter and no resolution yet.

    The box filter makes each pixel's estimate depend on its own samples only,
    which per-pixel error metrics and the methods' own splatting assume.
    """
    return {
        "type": "hdrfilm",
        "pixel_format": "rgb",
        "component_format": "float32",
        "rfilter": {"type": "box"},
    }


def sensor(origin: Vec3, target: Vec3, fov: float, up: Vec3 = (0.0, 1.0, 0.0)) -> SceneDict:
    """A perspective camera at ``origin`` looking at ``target`` (fov in degrees).

    ``fov_axis='smaller'`` keeps the framing when a caller asks for a
    non-square resolution. The sample count is a placeholder: renderers pass
    their own spp.
    """
    mi = mitsuba()
    return {
        "type": "perspective",
        "fov": float(fov),
        "fov_axis": "smaller",
        "near_clip": 0.01,
        "far_clip": 1000.0,
        "to_world": mi.ScalarTransform4f().look_at(
            origin=list(origin), target=list(target), up=list(up)
        ),
        "sampler": {"type": "independent", "sample_count": 16},
        "film": film(),
    }


def set_film_resolution(scene: SceneDict, width: int, height: int) -> SceneDict:
    """Write the film size into a built-in scene dictionary (in place) and return it."""
    scene[SENSOR_KEY]["film"]["width"] = int(width)
    scene[SENSOR_KEY]["film"]["height"] = int(height)
    return scene


# ---- Materials -------------------------------------------------------------

def rgb(value: RGB) -> SceneDict:
    return {"type": "rgb", "value": [float(c) for c in value]}


def diffuse(albedo: RGB) -> SceneDict:
    return {"type": "diffuse", "reflectance": rgb(albedo)}


def two_sided(bsdf: SceneDict) -> SceneDict:
    """Both faces scatter: thin walls seen from either side are never black."""
    return {"type": "twosided", "material": bsdf}


def rough_plastic(albedo: RGB, alpha: float) -> SceneDict:
    """Diffuse base under a GGX-rough dielectric coat (glossy, not delta)."""
    return {
        "type": "roughplastic",
        "distribution": "ggx",
        "alpha": float(alpha),
        "diffuse_reflectance": rgb(albedo),
    }


def rough_conductor(material: str, alpha: float) -> SceneDict:
    """A GGX-rough metal with tabulated complex IOR (e.g. 'Al', 'Au', 'Cu')."""
    return {
        "type": "roughconductor",
        "distribution": "ggx",
        "material": material,
        "alpha": float(alpha),
    }


def area_light(radiance: RGB) -> SceneDict:
    return {"type": "area", "radiance": rgb(radiance)}


# ---- Shapes ----------------------------------------------------------------

def _with(shape: SceneDict, bsdf: SceneDict | None, emitter: SceneDict | None) -> SceneDict:
    if bsdf is not None:
        shape["bsdf"] = bsdf
    if emitter is not None:
        shape["emitter"] = emitter
    return shape


def quad(
    center: Vec3,
    u: Vec3,
    v: Vec3,
    bsdf: SceneDict | None = None,
    emitter: SceneDict | None = None,
) -> SceneDict:
    """A parallelogram ``center + s u + t v`` for s, t in [-1, 1].

    Its normal (the side an area emitter lights) is ``normalize(u x v)``.
    Mitsuba's rectangle spans [-1, 1]^2 in the xy plane with normal +z, so the
    transform's columns are simply u, v, the unit normal and the centre.
    """
    u_, v_ = np.asarray(u, dtype=float), np.asarray(v, dtype=float)
    n = np.cross(u_, v_)
    n /= np.linalg.norm(n)
    matrix = np.eye(4)
    matrix[:3, 0], matrix[:3, 1], matrix[:3, 2] = u_, v_, n
    matrix[:3, 3] = np.asarray(center, dtype=float)
    shape = {"type": "rectangle", "to_world": mitsuba().ScalarTransform4f(matrix.tolist())}
    return _with(shape, bsdf, emitter)


def box(
    center: Vec3,
    half_size: Vec3,
    bsdf: SceneDict | None = None,
    yaw: float = 0.0,
    emitter: SceneDict | None = None,
) -> SceneDict:
    """An axis-aligned cuboid (before ``yaw``, a rotation in degrees about +y)."""
    mi = mitsuba()
    to_world = (
        mi.ScalarTransform4f()
        .translate(list(center))
        .rotate([0.0, 1.0, 0.0], float(yaw))
        .scale(list(half_size))
    )
    return _with({"type": "cube", "to_world": to_world}, bsdf, emitter)


def box_between(
    lo: Vec3, hi: Vec3, bsdf: SceneDict | None = None, emitter: SceneDict | None = None
) -> SceneDict:
    """The axis-aligned cuboid with corners ``lo`` and ``hi``."""
    lo_, hi_ = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    return box((lo_ + hi_) / 2, (hi_ - lo_) / 2, bsdf, emitter=emitter)


def sphere(center: Vec3, radius: float, bsdf: SceneDict | None = None) -> SceneDict:
    return _with(
        {"type": "sphere", "center": [float(c) for c in center], "radius": float(radius)},
        bsdf,
        None,
    )


def cylinder(p0: Vec3, p1: Vec3, radius: float, bsdf: SceneDict | None = None) -> SceneDict:
    """An open cylinder from ``p0`` to ``p1`` (no caps)."""
    return _with(
        {
            "type": "cylinder",
            "p0": [float(c) for c in p0],
            "p1": [float(c) for c in p1],
            "radius": float(radius),
        },
        bsdf,
        None,
    )


def room(lo: Vec3, hi: Vec3, bsdf: SceneDict, skip: Sequence[str] = ()) -> dict[str, SceneDict]:
    """The six inward-facing walls of the box [lo, hi], keyed floor/ceiling/±x/±z.

    Walls face inward so that one-sided emitters placed on them (and one-sided
    BSDFs) behave; ``skip`` leaves out walls a scene builds itself (e.g. one
    with a door opening).
    """
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    cx, cy, cz = (x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2
    hx, hy, hz = (x1 - x0) / 2, (y1 - y0) / 2, (z1 - z0) / 2
    walls = {
        # (centre, u, v) with u x v pointing into the room.
        "floor": ((cx, y0, cz), (0, 0, hz), (hx, 0, 0)),
        "ceiling": ((cx, y1, cz), (hx, 0, 0), (0, 0, hz)),
        "wall-x0": ((x0, cy, cz), (0, hy, 0), (0, 0, hz)),
        "wall-x1": ((x1, cy, cz), (0, 0, hz), (0, hy, 0)),
        "wall-z0": ((cx, cy, z0), (hx, 0, 0), (0, hy, 0)),
        "wall-z1": ((cx, cy, z1), (0, hy, 0), (hx, 0, 0)),
    }
    return {
        name: quad(c, u, v, bsdf) for name, (c, u, v) in walls.items() if name not in skip
    }
