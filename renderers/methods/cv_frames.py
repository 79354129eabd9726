"""What the control-variate methods (`cv-sh`, `cv-vmf`) share: parameters, the scenes
they apply to, and the frame loop that fits each pixel's model between frames.

The estimator is renderers.integrators.control_variate (NIRC paper Eq. 7 at the
first hits; docs/control_variates.md). A frame is one ``mi.render`` ('render': the
render also keeps its samples) followed by the model's fit from those samples
('fit'), so frame t's g is fitted from the samples of all frames
before it: the ``pretrain_frames`` fitting frames, the warm-up frame and frames
0..t-1 (every sample of every pixel's first hits), never from frame t's own.
Given the past, each frame is unbiased, so the frames' errors are uncorrelated
(martingale differences) though not independent.

==================  ========  ====================================================
parameter           default   meaning
==================  ========  ====================================================
max_depth           -1        longest path in segments (-1: unbounded; >= 2; at 2
                              the indirect integrand the model fits is 0)
uniform_fraction    0.25      probability of a uniform sphere sample in the
                              one-sample mixture with BSDF sampling (> 0)
pretrain_frames     0         frames rendered only to fit the model first
==================  ========  ====================================================
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pydantic import Field, model_validator

from renderers.methods.base import FrameHooks, MethodParams, RenderOutput, run_frames
from renderers.seeding import derive_seed
from renderers.timing import StageTimer


class ControlVariateParams(MethodParams):
    """The estimator's parameters (module docstring); a model's method adds its own."""

    max_depth: int = Field(-1, ge=-1, le=1024,
                           description="longest path in segments; -1 = unbounded, else >= 2")
    uniform_fraction: float = Field(0.25, gt=0.0, le=1.0,
                                    description="probability of a uniform sphere sample "
                                                "(the rest samples the BSDF)")
    pretrain_frames: int = Field(0, ge=0, le=100_000,
                                 description="frames rendered only to fit the model first")

    @model_validator(mode="after")
    def _depth_reaches_a_bounce(self) -> ControlVariateParams:
        if self.max_depth in (0, 1):
            raise ValueError("max_depth must be -1 (unbounded) or >= 2: the control "
                             "variate integrates the light reflected at the first hit")
        return self


def applies(features: Any) -> tuple[bool, str]:
    """A surface and no delta BSDF lobe (the estimator samples and evaluates only
    smooth lobes at the first hit)."""
    if features.shape_count == 0:
        return False, "the scene has no surface to shade"
    if features.has_delta:
        return False, "a delta BSDF lobe: the control variate samples only smooth lobes"
    return True, ""


class ModelFrames:
    """A frame function of the control-variate integrator: render, then fit."""

    def __init__(self, scene: Any, integrator: Any, model: Any, spp: int) -> None:
        self.scene, self.integrator, self.model, self.spp = scene, integrator, model, spp

    def __call__(self, _index: int, seed: int, timer: StageTimer) -> Any:
        import mitsuba as mi

        from renderers.timing import synchronize

        with timer.stage("render"):
            image = mi.render(self.scene.scene, integrator=self.integrator, spp=self.spp,
                              seed=seed)
            synchronize(image)
        with timer.stage("fit"):
            self.model.fit(self.integrator.records)
        return image


#: (method parameters, pixels) -> the model (renderers.integrators.control_variate).
ModelFactory = Callable[[Any, int], Any]


def film_pixels(scene: Any) -> int:
    """Pixels of the film's crop window (the lanes' pixel index runs over them)."""
    width, height = scene.scene.sensors()[0].film().crop_size()
    return int(width) * int(height)


def control_variate_render(make_model: ModelFactory,
                           model_stats: Callable[[Any], dict[str, Any]]) -> Callable[..., RenderOutput]:
    """The render function of a control-variate method whose per-pixel model
    ``make_model`` builds; ``model_stats(model)`` is stored with the run."""

    def render(scene: Any, params: ControlVariateParams, *, seed_parts: tuple[Any, ...],
               spp: int, frames: int, hooks: FrameHooks = FrameHooks()) -> RenderOutput:
        import mitsuba as mi

        from renderers.integrators import control_variate, register_plugins

        register_plugins()
        integrator = mi.load_dict({"type": control_variate.PLUGIN_NAME,
                                   "max_depth": params.max_depth,
                                   "uniform_fraction": params.uniform_fraction})
        model = make_model(params, film_pixels(scene))
        frame = ModelFrames(scene, integrator.with_model(model), model, spp)
        for index in range(params.pretrain_frames):
            frame(index, derive_seed(*seed_parts, "pretrain", index), StageTimer())
        output = run_frames(frame, seed_parts=seed_parts, frames=frames, spp=spp,
                            hooks=hooks)
        output.method_stats = {"pretrain_frames": params.pretrain_frames,
                               **model_stats(model)}
        return output

    return render
