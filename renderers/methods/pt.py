"""`pt`: the unbiased path-tracing baseline (the shared core with no cache)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal

from pydantic import Field, model_validator

from renderers.methods import register
from renderers.methods.base import (
    ComparisonRun,
    FrameHooks,
    Knob,
    Method,
    MethodParams,
    RenderOutput,
    render_stage,
    run_frames,
)

#: Unbounded: Russian roulette ends paths, as Mitsuba's ``path`` does by default.
#: Renders, references and cache-training paths share this depth (docs/training.md).
DEFAULT_MAX_DEPTH = -1


class PTParams(MethodParams):
    """Parameters of the path-tracing core (see renderers.integrators.path)."""

    max_depth: int = Field(DEFAULT_MAX_DEPTH, ge=-1, le=1024,
                           description="longest path in segments; -1 = unbounded")
    rr_depth: int = Field(5, ge=1, le=1024, description="first depth of Russian roulette")
    rr_mode: Literal["fixed", "throughput"] = Field(
        "fixed", description="Russian roulette: 'fixed' survives with rr_survival, "
                             "'throughput' with min(max(beta) eta^2, 0.95) (Mitsuba's rule)")
    rr_survival: float = Field(0.9, gt=0.0, le=1.0,
                               description="survival probability in rr_mode 'fixed'")

    @model_validator(mode="after")
    def _depth_not_zero(self) -> PTParams:
        if self.max_depth == 0:
            raise ValueError("max_depth must be -1 (unbounded) or >= 1")
        return self


def path_integrator(params: PTParams) -> Any:
    """A loaded instance of the shared path-tracing core with ``params``."""
    import mitsuba as mi

    from renderers.integrators import path, register_plugins

    register_plugins()
    return mi.load_dict({"type": path.PLUGIN_NAME, **params.model_dump()})


def render_with_lights(sampler: str | None) -> Callable[..., RenderOutput]:
    """The render function of the PT core selecting emitters with ``sampler`` (a class
    of renderers.integrators.lights, looked up when a render starts so that the
    registry never imports Mitsuba; None: the core's default, Mitsuba's selection)."""

    def render(scene: Any, params: PTParams, *, seed_parts: tuple[Any, ...], spp: int,
               frames: int, hooks: FrameHooks = FrameHooks()) -> RenderOutput:
        """Render ``frames`` frames of ``spp`` samples per pixel with the PT core."""
        integrator = path_integrator(params)
        if sampler is not None:
            from renderers.integrators import lights

            integrator.light_sampler_type = getattr(lights, sampler)
        return run_frames(render_stage(scene, integrator, spp), seed_parts=seed_parts,
                          frames=frames, spp=spp, hooks=hooks)

    return render


render = render_with_lights(None)


#: spp candidates of equal-time calibration.
SPP_CANDIDATES = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256, 384, 512)

METHOD = register(Method("pt", "unbiased path tracing: NEE + MIS + Russian roulette", PTParams, render,
                version=2, knob=Knob("spp", SPP_CANDIDATES),
                label="PT", unbiased=True,
                comparison=(ComparisonRun(0, "PT 1 spp", "PT 1 spp"),
                            ComparisonRun(1, "PT 2 spp", "PT 2 spp", spp=2, role="budget"))))
