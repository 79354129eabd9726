"""Helpers of the light-selection and environment-light tests (test_light_sampling.py,
test_nvc_lights.py, test_nvc_clusters.py, test_nvc_env.py, test_nirc_nvc_env.py)."""

from __future__ import annotations

from typing import Any

import numpy as np

from tests.renderers.scene_xml import perspective_sensor

#: Film resolution and samples per pixel of the statistical tests on `many-lights`.
RES = 16
SPP = 4096


def pt_integrator(mi: Any, sampler_type: Any = None, max_depth: int = 4) -> Any:
    """The PT core with ``max_depth``, selecting emitters with ``sampler_type`` (None: Mitsuba's)."""
    from renderers.integrators import path

    path.register()
    integrator = mi.load_dict({"type": path.PLUGIN_NAME, "max_depth": max_depth})
    if sampler_type is not None:
        integrator.light_sampler_type = sampler_type
    return integrator


def trained_nvc_lights(scene: Any, frames: int, seed: int = 0, **params: Any) -> tuple[Any, Any]:
    """(integrator, cache) of nvc-lights after ``frames`` frames of online training; a
    ``clamp`` below the accepted minimum (a planted defect) is set past validation."""
    from renderers.methods.nvc_lights import NVCLightsParams, build, train_frame
    from renderers.timing import StageTimer

    clamp = params.pop("clamp", None)
    parsed = NVCLightsParams(**params)
    if clamp is not None:
        parsed = parsed.model_copy(update={"clamp": clamp})
    integrator, cache = build(scene, parsed, seed)
    for frame in range(frames):
        train_frame(scene, cache, parsed, 100 * seed + frame, StageTimer())
    return integrator, cache


def luminance_moments(moments: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(mean, variance) of the Y channel of render_moments' XYZ moments."""
    mean, var = moments
    return mean[..., 1], var[..., 1]


def random_points(mi: Any, scene: Any, count: int = 64, seed: int = 3) -> tuple[Any, Any]:
    """Random points inside the scene's bounding box, as a surface interaction (and the rng)."""
    import drjit as dr

    rng = np.random.default_rng(seed)
    box = scene.bbox()
    lo, hi = np.array(box.min), np.array(box.max)
    p = lo + rng.uniform(size=(count, 3)) * (hi - lo)
    si = dr.zeros(mi.SurfaceInteraction3f, count)
    si.p = mi.Point3f(*(mi.Float(p[:, k]) for k in range(3)))
    return si, rng


#: A constant environment and a spherical area light over a floor and a rough metal sphere.
ENV_AND_SPHERE = """<scene version="3.0.0">
    """ + perspective_sensor("45", "0, 1, 4", "0, 0.5, 0") + """
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale value="3"/></transform>
        <bsdf type="diffuse"/>
    </shape>
    <shape type="sphere">
        <point name="center" value="0, 0.5, 0"/><float name="radius" value="0.5"/>
        <bsdf type="roughconductor"><float name="alpha" value="0.2"/></bsdf>
    </shape>
    <shape type="sphere">
        <point name="center" value="1, 2.5, 1"/><float name="radius" value="0.3"/>
        <emitter type="area"><rgb name="radiance" value="20, 18, 15"/></emitter>
    </shape>
    <emitter type="constant"><rgb name="radiance" value="0.1, 0.12, 0.2"/></emitter>
</scene>
"""


class ShadowRayOracle:
    """A visibility "cache" returning the exact visibility of one shadow ray (``zero``:
    always 0); ``radiance``: the environment's radiance times it, RGB (what nvc-env's
    ``target='radiance'`` cache predicts). Its surface features are the position and
    the normal (to offset the ray)."""

    def __init__(self, scene: Any, zero: bool = False, radiance: bool = False) -> None:
        self.scene, self.zero, self.radiance = scene, zero, radiance

    def surface_features(self, position: Any, normal: Any = None, **_: Any) -> list[Any]:
        return [*position, *normal]

    def query(self, surface: list[Any], direction: Any) -> list[Any]:
        import drjit as dr
        import mitsuba as mi

        si = dr.zeros(mi.SurfaceInteraction3f)
        si.p, si.n = mi.Point3f(*surface[:3]), mi.Normal3f(*surface[3:])
        visible = mi.Float(0) if self.zero else dr.select(
            self.scene.ray_test(si.spawn_ray(direction)), 0.0, 1.0)
        if not self.radiance:
            return [visible]
        si.wi = -direction
        value = self.scene.environment().eval(si) * visible
        return [value[0], value[1], value[2]]
