"""The neural control variate `ncv` (renderers/caches/ncv.py, renderers/methods/ncv.py):
unbiased with power against a closed-form reference, a planted wrong integral rejected,
the method's renders reproducible with their memory stored.

The reference is the furnace of test_control_variates.py (the camera inside a diffuse,
uniformly emitting sphere: every pixel's expectation is known in closed form); per-pixel
Šidák z-test and block chi^2 (metrics.statistics.agreement_test) on per-pixel moments.
The networks are small (the estimator, not the capacity, is under test; the flow's own
tests take the paper's sizes) and trained for a few frames of 64 samples a pixel.
"""

from __future__ import annotations

import drjit as dr
import numpy as np
import pytest

from metrics.statistics import agreement_test
from renderers.methods import MethodError, get_method, parse_params
from tests.renderers.test_control_variates import (
    FURNACE,
    FURNACE_SPP,
    RES,
    ScaledIntegral,
    _furnace_expectation,
    _integrator,
    _load,
    _zero,
)
from tests.support.moments import render_moments

#: A small model: 16 bins, MLPs of 2 x 32, a 4-level hash grid, steps of 1024 samples.
SMALL = {"flow": {"bins": 16, "width": 32, "hidden_layers": 2},
         "integral_width": 32, "integral_hidden_layers": 2,
         "position": {"n_levels": 4, "log2_hashmap_size": 10, "base_resolution": 4},
         "batch_size": 1024, "steps_per_frame": 2, "learning_rate": 2e-2}
#: Training: frames of SPP samples a pixel (the method render below uses the same spp,
#: so that both compile the same kernels).
FRAMES, SPP = 3, 64


@pytest.fixture(scope="module")
def furnace(mi, tmp_path_factory):
    return _load(tmp_path_factory, FURNACE)


def _model(scene):
    """The small model, untrained (G = 0)."""
    from renderers.caches.ncv import NCVConfig, NCVModel

    return NCVModel(NCVConfig(**SMALL), scene.scene, seed=1)


def _rendering(mi, model):
    """The estimator with ``model``, keeping no samples."""
    integrator = _integrator(mi, model)
    integrator.fitting = False
    return integrator


@pytest.fixture(scope="module")
def trained(mi, furnace):
    """The model trained for FRAMES frames (then frozen)."""
    model = _model(furnace)
    integrator = _integrator(mi, model)
    for frame in range(FRAMES):
        mi.render(furnace.scene, integrator=integrator, spp=SPP, seed=1000 + frame)
        model.fit(integrator.records)
    return model


@pytest.fixture(scope="module")
def trained_moments(mi, furnace, trained):
    """Per-pixel mean and variance of the trained control variate's estimate."""
    return render_moments(furnace.scene, _rendering(mi, trained), FURNACE_SPP, seed=2)


def test_ncv_agrees_with_the_furnace(mi, trained_moments):
    result = agreement_test(*trained_moments, *_furnace_expectation(mi))
    assert result.passed, result.summary()


def test_ncv_lowers_the_variance_below_the_plain_estimator(mi, furnace, trained_moments):
    """Against the plain estimator (g = 0: the first frame's)."""
    _, plain_variance = render_moments(furnace.scene, _zero(mi), FURNACE_SPP, seed=3)
    ratio = np.median(trained_moments[1] / plain_variance)   # measured 0.66 (0.15 after 32)
    assert ratio < 0.8, f"median variance ratio NCV / plain {ratio:.3f}"


def test_a_scaled_integral_is_rejected(mi, furnace, trained):
    """G scaled by 1.05, g unchanged: biased, and the agreement test rejects it."""
    integrator = _rendering(mi, ScaledIntegral(trained))
    assert not agreement_test(*render_moments(furnace.scene, integrator, FURNACE_SPP, seed=4),
                              *_furnace_expectation(mi)).passed


def test_an_ncv_render_is_reproducible_and_stores_its_memory(mi, furnace):
    from tests.support.untimed import UNTIMED

    method = get_method("ncv")
    values = parse_params("ncv", {"max_depth": 3, "ncv": {**SMALL, "steps_per_frame": 1}})
    a, b = (method.render(furnace, values, seed_parts=("ncv",), spp=SPP, frames=1,
                          hooks=UNTIMED) for _ in range(2))
    np.testing.assert_array_equal(a.accumulated, b.accumulated)
    model = a.method_stats["model"]
    per_pixel = model["floats_per_pixel"]["per_pixel_buffers"]
    assert per_pixel == {"surface": 6, "condition": 4 * 2 + 3 * 4, "integral": 3}
    shared = sum(model["parameters"].values()) / (RES * RES)
    assert model["floats_per_pixel"]["model"] == pytest.approx(sum(per_pixel.values()) + shared)
    assert model["steps"] == 2 and model["nonfinite_samples"] == 0   # warm-up and frame
    assert set(a.timings["stages"]) == {"render", "fit"}


def _collapsed(mi, scene, mix):
    """A small model whose every coupling transform has collapsed as training on sky
    collapsed them (renderers.caches.flow, "A floor under the bins"): all the mass in
    the first bin (the heights of the other vertices exp(-200) = 0 in float), so a
    transform maps most of the square onto its edge u = 1, where the next transform of
    that coordinate has a last bin of width 0; G = 1 (G = 0 sends the flow no
    gradient)."""
    from renderers.caches.ncv import NCVConfig, NCVModel

    config = NCVConfig(**{**SMALL, "flow": {**SMALL["flow"], "uniform_mix": mix}})
    model = NCVModel(config, scene.scene, seed=1)
    bins, last = config.flow.bins, f"layers.{2 * config.flow.hidden_layers}"
    raw = np.zeros(config.flow.raw_outputs, dtype=np.float32)
    raw[bins - 1] = raw[bins + 1:] = -200.0
    for key in list(model.optimizer):
        if key.startswith("flow.") and key.endswith(f"{last}.weights"):
            model.optimizer[key] = dr.zeros(mi.TensorXf, model.optimizer[key].shape)
        elif key.startswith("flow.") and key.endswith(f"{last}.bias"):
            model.optimizer[key] = mi.TensorXf(raw)
        elif key == f"integral.layers.{2 * config.integral_hidden_layers}.bias":
            model.optimizer[key] = dr.ones(mi.TensorXf, model.optimizer[key].shape)
    model._refresh()
    return model


def _all_finite(model) -> bool:
    return all(np.isfinite(np.asarray(model.optimizer[key].array)).all()
               for key in model.optimizer)


@pytest.fixture(scope="module")
def records(mi, furnace):
    """One frame's samples (64 a pixel) of the furnace, rendered with collapsed bins."""
    integrator = _integrator(mi, _collapsed(mi, furnace, 1e-3))
    mi.render(furnace.scene, integrator=integrator, spp=SPP, seed=1000)
    return integrator.records


def _g_finite(mi, model, records) -> bool:
    """g at the records' first 1024 samples with a direction is finite."""
    lanes = mi.UInt32(np.flatnonzero(np.asarray(records.pdf) > 0)[:1024])
    g = model.eval(lanes // records.spp, dr.gather(mi.Vector3f, records.w, lanes),
                   mi.Bool(True))
    return bool(np.isfinite(np.asarray(g)).all())


def test_collapsed_bins_keep_the_model_finite_and_training(mi, furnace, records):
    """Training on sky 16x16 collapsed the bins (smallest width 1e-14 after 40 steps)
    until g was non-finite and every step's loss too. With the flow's floor, collapsed
    bins still give a finite g and a fit takes its steps; planted: without the floor
    (``uniform_mix`` 0, the code before the fix) g is non-finite and every step is
    skipped."""
    floored = _collapsed(mi, furnace, 1e-3)
    assert _g_finite(mi, floored, records)
    floored.fit(records)
    assert (floored.steps, floored.skipped_steps) == (SMALL["steps_per_frame"], 0)
    assert _all_finite(floored) and _g_finite(mi, floored, records)

    unfloored = _collapsed(mi, furnace, 0.0)
    assert not _g_finite(mi, unfloored, records)
    unfloored.fit(records)
    assert (unfloored.steps, unfloored.skipped_steps) == (0, SMALL["steps_per_frame"])


def _nan_gradient_backward(model):
    """``dr`` for renderers.caches.ncv whose backward leaves a NaN in one gradient entry
    of the hash grid after the true backward pass: a finite loss with a non-finite
    gradient, as one step on sky had once its bins were ~1e-27 wide (every weight was
    NaN after it)."""
    from types import SimpleNamespace

    import mitsuba as mi

    from renderers.caches.ncv import GRID_KEY

    def backward(loss):
        dr.backward(loss)
        grid = model.optimizer[GRID_KEY]
        first = dr.arange(mi.UInt32, dr.width(grid)) == 0
        dr.accum_grad(grid, dr.select(first, float("nan"), 0.0))

    return SimpleNamespace(**{**vars(dr), "backward": backward})


def test_a_step_with_a_non_finite_gradient_is_skipped(mi, furnace, records, monkeypatch):
    """A finite loss whose gradient holds a NaN: the fit skips its steps and the weights
    stay finite; planted: with only the loss checked (the code before the fix) the
    weights are NaN after the fit."""
    from renderers.caches import ncv
    from renderers.caches.ncv import NCVModel

    model = _collapsed(mi, furnace, 1e-3)
    monkeypatch.setattr(ncv, "dr", _nan_gradient_backward(model))
    model.fit(records)
    assert (model.steps, model.skipped_steps) == (0, SMALL["steps_per_frame"])
    assert model.loss_history == [] and _all_finite(model)

    monkeypatch.setattr(NCVModel, "_finite",
                        lambda self, loss: mi.Bool(bool(dr.isfinite(loss)[0])))
    unguarded = _collapsed(mi, furnace, 1e-3)
    monkeypatch.setattr(ncv, "dr", _nan_gradient_backward(unguarded))
    unguarded.fit(records)
    assert unguarded.steps == SMALL["steps_per_frame"] and not _all_finite(unguarded)


@pytest.mark.parametrize("values, fragment", [
    ({"ncv": {"flow": {"bins": 1}}}, "ncv: flow.bins"),
    ({"ncv": {"batch_size": 0}}, "ncv: batch_size"),
    ({"ncv": {"lobes": 3}}, "ncv: lobes"),
    ({"max_depth": 1}, "max_depth"),
])
def test_invalid_ncv_parameters(values, fragment):
    with pytest.raises(MethodError, match=fragment):
        parse_params("ncv", values)
