"""[DKHD24] Fig. 6's curves: V_rel(<F_r>) after every training frame of NCV and of
unbiased NIRC (6 hidden layers), smoothed by an exponential moving average as the paper
plots it (alpha 0.95).

One seed per scene and method, trained online from scratch (no pre-training), one-spp
frames; after frame t an untimed probe of 2 residual samples a pixel with the model or
cache of that moment gives V_rel_t (docs/metrics.md: the same probe as the table's, which
takes it after the last frame only), and

    EMA_1 = V_rel_1,    EMA_t = alpha EMA_{t-1} + (1 - alpha) V_rel_t.

A frame without a V_rel (no pixel with two finite residual samples) leaves the average
as it was and is counted, never averaged in. The curve is kept at :func:`kept_frames`
(about two a doubling of t) for the table and the plot."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from types import SimpleNamespace
from typing import Any

ALPHA = 0.95
#: The residual probe's samples per pixel after each frame.
PROBE_SPP = 2


def moving_average(values: Iterable[float | None], alpha: float = ALPHA
                   ) -> tuple[list[float | None], int]:
    """The EMA after each value (module docstring) and how many values were missing or
    not finite (each leaves the average unchanged; None before the first finite one)."""
    averages: list[float | None] = []
    current: float | None = None
    missing = 0
    for value in values:
        if value is None or not math.isfinite(value):
            missing += 1
        elif current is None:
            current = value
        else:
            current = alpha * current + (1.0 - alpha) * value
        averages.append(current)
    return averages, missing


def kept_frames(frames: int) -> list[int]:
    """Frames t (1-based) kept of a curve of ``frames``: 1, 2, 3, 4, 6, 8, 12, 16, ...
    and the last."""
    kept, power = set(), 1
    while power <= frames:
        kept.update(t for t in (power, power + power // 2) if t <= frames)
        power *= 2
    return sorted(kept | {frames})


def ncv_frames(scene: Any, params: Any, seed_parts: tuple[Any, ...], frames: int,
               after_frame: Callable[[Any], None] | None) -> Any:
    """`ncv` trained ``frames`` frames as its method trains it: :func:`model_frames`."""
    from renderers.methods.ncv import ncv_model

    return model_frames(ncv_model, scene, params, seed_parts, frames, after_frame)


def model_frames(make_model: Callable[..., Any], scene: Any, params: Any,
                 seed_parts: tuple[Any, ...], frames: int,
                 after_frame: Callable[[Any], None] | None) -> Any:
    """The control-variate model ``make_model`` builds (renderers.methods.cv_frames'
    factories) trained ``frames`` frames as its method trains it (render, then fit), the
    residual probe after each (none without ``after_frame``); returns the model."""
    import mitsuba as mi

    from renderers.integrators import control_variate, register_plugins
    from renderers.methods.cv_frames import ModelFrames, probe_residuals
    from renderers.seeding import derive_seed
    from renderers.timing import StageTimer

    register_plugins()
    integrator = mi.load_dict({"type": control_variate.PLUGIN_NAME,
                               "max_depth": params.max_depth,
                               "uniform_fraction": params.uniform_fraction})
    model = make_model(params, scene, seed_parts)
    frame = ModelFrames(scene, integrator.with_model(model), model, 1)
    for index in range(frames):
        frame(index, derive_seed(*seed_parts, index), StageTimer())
        if after_frame is None:
            continue
        probe = SimpleNamespace(method_stats={}, residual_variance=None)
        probe_residuals(scene, integrator, model, probe, spp=PROBE_SPP,
                        seed=derive_seed(*seed_parts, "residual probe", index))
        after_frame(probe.residual_variance)
    return model


def nirc_frames(scene: Any, params: Any, seed_parts: tuple[Any, ...], frames: int,
                after_frame: Callable[[Any], None] | None) -> tuple[Any, Any]:
    """Unbiased `nirc` trained ``frames`` frames as its method trains it
    (renderers.methods.cached: a training step before each frame), the residual probe
    after each (none without ``after_frame``); returns its integrator and cache."""
    from renderers.methods import get_method
    from renderers.methods.base import FrameHooks
    from renderers.methods.cached import probe_residuals, render_with_cache
    from renderers.seeding import derive_seed

    integrator, trainer, cache = get_method("nirc").build(scene, params,
                                                          derive_seed(*seed_parts, "cache"))

    def probe(index: int, _rgb: Any, _accumulated: Any) -> None:
        if after_frame is None:
            return
        result = SimpleNamespace(method_stats={}, residual_variance=None)
        probe_residuals(scene, params, cache, result, spp=PROBE_SPP,
                        seed=derive_seed(*seed_parts, "residual probe", index))
        after_frame(result.residual_variance)

    render_with_cache(scene, params, integrator, trainer, cache, seed_parts=seed_parts,
                      spp=1, frames=frames, hooks=FrameHooks(on_frame=probe, warmup=False))
    return integrator, cache


def v_rel_curve(train: Callable[..., None], scene: Any, params: Any,
                seed_parts: tuple[Any, ...], frames: int, reference: Any,
                eps: float) -> list[float | None]:
    """V_rel after each of ``frames`` training frames (None where no pixel had one)."""
    from metrics.residual_variance import relative_residual_variance

    curve: list[float | None] = []
    train(scene, params, seed_parts, frames,
          lambda variance: curve.append(None if variance is None else
                                        relative_residual_variance(variance, reference, eps)))
    return curve
