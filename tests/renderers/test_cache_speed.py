"""The speed levers of the neural cache (docs/training.md, "Speed of the neural work").

The small network preset, the optional converged-loss step rule (off by
default, so the presets train their full budget), and that consecutive
frames of training and queries reuse their compiled kernels.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import pytest
from pydantic import ValidationError

import renderers.caches as caches
from renderers.methods import parse_params
from tests.renderers.test_caches import query_records, small_config, synthetic_records

pytestmark = pytest.mark.usefixtures("mi")


@pytest.mark.parametrize("preset_fn", [caches.nirc_config, caches.nrc_config])
def test_small_preset_is_a_2x32_mlp_with_the_same_inputs(preset_fn):
    default, small = preset_fn(), preset_fn(preset="small")
    assert (small.mlp.width, small.mlp.hidden_layers) == (32, 2)
    assert small.model_copy(update={"mlp": default.mlp}) == default
    # Explicit overrides still apply on top of the preset.
    assert preset_fn(preset="small", mlp={"width": 16}).mlp.width == 16
    with pytest.raises(ValueError, match="unknown cache preset"):
        preset_fn(preset="tiny")


def test_small_preset_reaches_methods_through_their_cache_parameter():
    params = parse_params("nirc", {"cache": {"preset": "small"}})
    assert caches.nirc_config(**params.cache).mlp.width == 32


def test_small_preset_builds_and_trains():
    config = caches.nirc_config(preset="small", position={"n_levels": 6, "log2_hashmap_size": 12},
                                batch_size=2048)
    cache = caches.NeuralCache(config, [0, 0, 0], [1, 1, 1], seed=3)
    rec = synthetic_records(8192, seed=1)
    losses = cache.train(rec, steps=40)
    assert len(losses) == 40 and losses[-1] < 0.5 * losses[0]
    out = query_records(cache, rec)
    dr.eval(out)
    assert dr.all(dr.isfinite(out.x))


def test_converged_rule_is_off_by_default():
    assert caches.nirc_config().converged_training is None
    assert caches.nrc_config().converged_training is None
    cache = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1], seed=0)
    rec = synthetic_records(4096)
    for _ in range(3):
        assert len(cache.train(rec)) == 4
    assert cache.stats["reduced_frames"] == 0 and not cache.loss_converged()


def test_converged_rule_follows_the_moving_average_of_the_frame_loss():
    rule = {"window": 2, "tolerance": 0.05, "ema_decay": 0.5, "steps": 1}
    cache = caches.NeuralCache(small_config(converged_training=rule), [0, 0, 0], [1, 1, 1])
    # E_f = 0.5 E_{f-1} + 0.5 m_f
    cache.frame_loss_ema[:] = [1.0, 0.5]
    assert not cache.loss_converged()            # fewer than window + 1 frames
    cache.frame_loss_ema.append(0.49)
    assert not cache.loss_converged()            # |0.49 - 1.0| >= 5 % of 1.0
    cache.frame_loss_ema[:] = [1.0, 0.5, 0.5, 0.49]
    assert cache.loss_converged()                # |0.49 - 0.5| < 5 % of 0.5
    rec = synthetic_records(4096)
    losses = cache.train(rec, steps=4)
    assert len(losses) == 1 and cache.stats["reduced_frames"] == 1
    assert cache.frame_loss_ema[-1] == pytest.approx(0.5 * 0.49 + 0.5 * losses[0])


def test_converged_rule_trains_fewer_steps_once_the_loss_settles():
    rule = {"window": 3, "tolerance": 0.2, "ema_decay": 0.5, "steps": 1}
    cache = caches.NeuralCache(small_config(converged_training=rule, batch_size=1024),
                               [0, 0, 0], [1, 1, 1], seed=0)
    rec = synthetic_records(4096)
    taken = [len(cache.train(rec, steps=4)) for _ in range(30)]
    assert taken[:rule["window"] + 1] == [4] * (rule["window"] + 1)
    assert 1 in taken and set(taken) == {1, 4}
    assert cache.stats["reduced_frames"] == taken.count(1)
    assert cache.stats["steps"] == sum(taken)


def test_converged_rule_validates():
    with pytest.raises(ValidationError):
        caches.nirc_config(converged_training={"steps": 0})
    with pytest.raises(ValidationError):
        caches.nirc_config(converged_training={"tolerance": 0.0})
    config = caches.nirc_config(converged_training={"window": 4})
    assert caches.CacheConfig.from_json(config.to_json()) == config


def _new_kernels() -> int:
    """Kernels since the last call that were compiled or loaded from the disk cache."""
    return sum(1 for k in dr.kernel_history()
               if k["type"] == dr.KernelType.JIT and (not k["cache_hit"] or k["cache_disk"]))


def test_consecutive_frames_reuse_their_kernels():
    """A frame (train with a decaying learning rate, then query) compiles nothing
    new once the EMA and the optimizer have started: no per-frame literal
    (step count, learning rate, EMA debiasing) is baked into a kernel."""
    config = small_config(optimizer={"lr_end": 1e-3, "lr_decay_steps": 50})
    cache = caches.NeuralCache(config, [0, 0, 0], [1, 1, 1], seed=0)
    rec = synthetic_records(4096)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        new = []
        for _ in range(6):
            cache.train(rec, steps=2, batch_size=1024)
            out = query_records(cache, rec)
            dr.eval(out)
            dr.sync_thread()
            new.append(_new_kernels())
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        dr.kernel_history()
    assert new[-2:] == [0, 0], new


@pytest.mark.parametrize("poison", [False, True])
def test_fixed_point_grid_gradient_is_finite_everywhere_or_nowhere(poison):
    """The training step's guard takes the table gradient's finiteness from the
    lookup's flag instead of reading the table (cache.py, _step): that is exact
    only because a non-finite incoming gradient makes every entry NaN and a
    finite one none."""
    import numpy as np

    cache = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1], seed=0)
    rec = synthetic_records(1024, seed=2)
    data = dr.detach(cache.encoder.position.grid.data)
    dr.enable_grad(data)
    rows = cache.encoder.position.with_data(data).encode(rec.position)
    weight = dr.full(mi.Float, 1.0, 1024)
    if poison:
        dr.scatter(weight, dr.nan, mi.UInt32(17))
    dr.backward(dr.sum(sum(r * weight for r in rows)))
    grad = np.asarray(dr.grad(data))
    assert (np.isnan(grad).all() if poison else np.isfinite(grad).all())
    lookup = cache.encoder.position.with_data(data).lookup   # not the training copy
    assert lookup is None


@pytest.mark.parametrize("frozen", [False, True])
def test_a_step_with_a_non_finite_grid_gradient_is_skipped(monkeypatch, frozen):
    """The guard sees a NaN table gradient through the lookup's flag alone. A frozen step
    replays the backward it recorded, so there the poison is planted before the step
    is first recorded (every step skipped); traced, after a first good step."""
    import numpy as np

    import renderers.caches.grid_grad as grid_grad
    from renderers.frozen import frozen_frames

    backward = grid_grad.DeterministicGridLookup.backward

    def poisoned(self):
        backward(self)
        self.handle.finite = mi.Bool(False)

    rec = synthetic_records(2048, seed=3)
    with frozen_frames(frozen):
        cache = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1], seed=1)
    taken = 0 if frozen else len(cache.train(rec, steps=1))
    before = cache.parameters()
    monkeypatch.setattr(grid_grad.DeterministicGridLookup, "backward", poisoned)
    assert cache.train(rec, steps=2) == []
    assert cache.stats["skipped_steps"] == 2 and cache.stats["steps"] == taken
    after = cache.parameters()
    for key, value in before.items():
        np.testing.assert_array_equal(value, after[key])
