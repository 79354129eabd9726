"""What the control-variate methods (`cv-sh`, `cv-vmf`) share: parameters, the scenes
they apply to, the frame loop that fits each pixel's model between frames, and the
method built around a model (:func:`control_variate_method`: a method module adds its
model's parameters and factory).

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

from renderers.methods import register
from renderers.methods.base import (
    FrameHooks,
    Knob,
    Method,
    MethodParams,
    RenderOutput,
    run_frames,
)
from renderers.methods.pt import SPP_CANDIDATES
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
    """A frame function of the control-variate integrator: render, then fit. The render
    is frozen (renderers.frozen) while freezing is on and the model allows it
    (``freezable``: the SH and vMF models do), the model's data handed over as
    its argument every frame and the kept samples returned; :meth:`settle` runs it
    alone, which changes no state (the warm-up fits once, frozen or not)."""

    def __init__(self, scene: Any, integrator: Any, model: Any, spp: int) -> None:
        from renderers.frozen import Frozen, freezing, weak_method

        self.scene, self.integrator, self.model, self.spp = scene, integrator, model, spp
        self.frozen = (Frozen(weak_method(self._render), auto_opaque=False)
                       if freezing() and model.freezable else None)
        if self.frozen is not None:
            self.recordings = self.frozen.recordings

    def _render(self, scene: Any, seed: Any, state: dict[str, Any]) -> tuple[Any, Any]:
        import mitsuba as mi

        self.model.bind(state)
        image = mi.render(scene, integrator=self.integrator, spp=self.spp, seed=seed)
        return image, self.integrator.records.arrays()

    def _render_frame(self, seed: int) -> Any:
        """The frame's image; the integrator keeps its samples (``records``)."""
        import mitsuba as mi

        from renderers.integrators.control_variate_records import SampleRecords
        from renderers.timing import synchronize

        if self.frozen is None:
            image = mi.render(self.scene.scene, integrator=self.integrator, spp=self.spp,
                              seed=seed)
        else:
            state = self.model.state()
            image, arrays = self.frozen(self.scene.scene, mi.UInt32(seed), state)
            # A recording bound the model to its own inputs: bind the frame's again.
            self.model.bind(state)
            self.integrator.records = SampleRecords.of(arrays, self.spp)
        synchronize(image)
        return image

    def __call__(self, _index: int, seed: int, timer: StageTimer) -> Any:
        with timer.stage("render"):
            image = self._render_frame(seed)
        with timer.stage("fit"):
            self.model.fit(self.integrator.records)
        return image

    def settle(self, _index: int, seed: int, timer: StageTimer) -> None:
        with timer.stage("render"):
            self._render_frame(seed)


#: (method parameters, scene, seed parts) -> the model (renderers.integrators.
#: control_variate), zero (g = 0) until its first fit.
ModelFactory = Callable[[Any, Any, tuple[Any, ...]], Any]


def film_pixels(scene: Any) -> int:
    """Pixels of the film's crop window (the lanes' pixel index runs over them)."""
    width, height = scene.scene.sensors()[0].film().crop_size()
    return int(width) * int(height)


def control_variate_render(make_model: ModelFactory) -> Callable[..., RenderOutput]:
    """The render function of a control-variate method whose per-pixel model
    ``make_model`` builds; the model's ``stats()`` are stored with the run."""

    def render(scene: Any, params: ControlVariateParams, *, seed_parts: tuple[Any, ...],
               spp: int, frames: int, hooks: FrameHooks = FrameHooks()) -> RenderOutput:
        import mitsuba as mi

        from renderers.integrators import control_variate, register_plugins

        register_plugins()
        integrator = mi.load_dict({"type": control_variate.PLUGIN_NAME,
                                   "max_depth": params.max_depth,
                                   "uniform_fraction": params.uniform_fraction})
        model = make_model(params, scene, seed_parts)
        frame = ModelFrames(scene, integrator.with_model(model), model, spp)
        for index in range(params.pretrain_frames):
            frame(index, derive_seed(*seed_parts, "pretrain", index), StageTimer())
        output = run_frames(frame, seed_parts=seed_parts, frames=frames, spp=spp,
                            hooks=hooks)
        output.method_stats = {"pretrain_frames": params.pretrain_frames,
                               "model": model.stats()}
        probe_residuals(scene, integrator, model, output, spp=max(spp, 2),
                        seed=derive_seed(*seed_parts, "residual probe"))
        return output

    return render


def probe_residuals(scene: Any, integrator: Any, model: Any, output: RenderOutput, *,
                    spp: int, seed: int) -> None:
    """After the frame loop, untimed: ``spp`` residual samples (f - g) / q per pixel with
    the final ``model`` (one render that keeps its samples and fits nothing; the render
    frames are untouched), their per-pixel variance kept as ``output.residual_variance``
    for V_rel (docs/metrics.md; renderers.methods.cached.keep_residual_variance)."""
    import mitsuba as mi

    from renderers.methods.cached import keep_residual_variance

    width, height = scene.scene.sensors()[0].film().crop_size()
    fitting, integrator.fitting = integrator.fitting, True
    try:
        mi.render(scene.scene, integrator=integrator, spp=spp, seed=seed)
        values, probed = integrator.records.residuals(model, int(width), int(height))
    finally:
        integrator.fitting = fitting
    keep_residual_variance(output, values, probed, spp=spp)


def control_variate_method(name: str, description: str, params: type[ControlVariateParams],
                           make_model: ModelFactory, *, version: int, label: str,
                           unbiased: bool | None) -> Method:
    """The registered Method of a control-variate model: the frames above, the scenes
    :func:`applies` accepts, spp as its knob; ``unbiased``: what it claims (NIRC Eq. 7
    is unbiased whatever the fit; docs/control_variates.md says what is claimed)."""
    return register(Method(name, description, params, control_variate_render(make_model),
                           version=version, requires=applies, label=label,
                           knob=Knob("spp", SPP_CANDIDATES), unbiased=unbiased))
