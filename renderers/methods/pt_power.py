"""`pt-power`: the PT core with emitters selected in proportion to their power.

The light sampler is :class:`renderers.integrators.lights.PowerLightSampler`
(pbrt-v4's ``PowerLightSampler``): p(i) ∝ Φ_i, Φ_i ≈ π · area · mean
luminance of an area emitter (4π² R² · mean luminance for an environment),
computed once per scene. It drives NEE and the MIS weight of BSDF-sampled
emitter hits alike, so the estimator stays unbiased (docs/estimators.md,
"Light selection").
"""

from __future__ import annotations

from typing import Any

from renderers.methods.base import FrameHooks, Method, RenderOutput, render_stage, run_frames
from renderers.methods.pt import PATH_INTEGRATORS, PTParams, path_integrator


class PTPowerParams(PTParams):
    """The path-tracing core's parameters; the selector has none of its own."""


def render(scene: Any, params: PTPowerParams, *, seed_parts: tuple[Any, ...], spp: int,
           frames: int, hooks: FrameHooks = FrameHooks()) -> RenderOutput:
    """Render ``frames`` frames of ``spp`` samples per pixel, power-proportional selection."""
    from renderers.integrators.lights import PowerLightSampler

    integrator = path_integrator(params)
    integrator.light_sampler_type = PowerLightSampler
    return run_frames(render_stage(scene, integrator, spp), seed_parts=seed_parts,
                      frames=frames, spp=spp, hooks=hooks)


METHOD = Method("pt-power", "path tracing with emitters selected in proportion to power",
                PTPowerParams, render, version=1, integrators=PATH_INTEGRATORS)
