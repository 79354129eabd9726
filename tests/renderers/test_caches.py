"""Tests of the shared neural cache (renderers/caches): config, encodings,
training robustness, reproducibility, and inference inside Mitsuba loops."""

from __future__ import annotations

import copy
import json

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from pydantic import ValidationError

import renderers.caches as caches
from renderers.caches import encodings as enc

# Every test needs the Mitsuba variant selected by the backend (conftest `mi`).
pytestmark = pytest.mark.usefixtures("mi")


def small_config(**overrides):
    """A cheap NIRC-shaped config (small grid and MLP) so tests compile and run fast."""
    base = {
        "position": {"n_levels": 6, "log2_hashmap_size": 12, "base_resolution": 4},
        "mlp": {"width": 32, "hidden_layers": 2},
        "batch_size": 2048,
    }
    return caches.nirc_config(**{**base, **overrides})


def smooth_target(p, d):
    """A smooth positive radiance over the unit box, varying with position and direction."""
    return mi.Color3f(
        1.0 + 0.5 * dr.sin(3.0 * p.x) + 0.3 * d.z,
        1.0 + 0.5 * dr.cos(2.0 * p.y) * d.x,
        0.5 + 0.4 * p.z * p.z + 0.2 * d.y,
    )


def synthetic_records(n, seed=0):
    rng = dr.rng(seed)
    p = mi.Point3f(rng.random(mi.Float, n), rng.random(mi.Float, n), rng.random(mi.Float, n))
    d = dr.normalize(mi.Vector3f(rng.normal(mi.Float, n), rng.normal(mi.Float, n),
                                 rng.normal(mi.Float, n)))
    normal = dr.normalize(mi.Vector3f(rng.normal(mi.Float, n), rng.normal(mi.Float, n),
                                      rng.normal(mi.Float, n)))
    return caches.TrainingRecords(
        position=p,
        target=smooth_target(p, d),
        normal=normal,
        roughness=rng.random(mi.Float, n),
        albedo=mi.Color3f(rng.random(mi.Float, n), dr.full(mi.Float, 0.5, n),
                          dr.full(mi.Float, 0.25, n)),
        direction=d,
    )


def query_records(cache, rec):
    surface = cache.surface_features(rec.position, rec.normal, rec.roughness, rec.albedo,
                                     rec.albedo_spec)
    return cache.query(surface, rec.direction)


def as_numpy(values):
    """Rows of Dr.Jit arrays -> 2-D NumPy array (width-1 constant rows broadcast)."""
    rows = [np.asarray(v, dtype=np.float32).reshape(-1) for v in values]
    n = max(r.size for r in rows)
    return np.array([np.broadcast_to(r, (n,)) for r in rows])


# --------------------------------------------------------------------------
# Config
# --------------------------------------------------------------------------

def test_presets_have_the_documented_shape():
    nirc = caches.nirc_config()
    assert nirc.position.n_levels == 12 and nirc.position.n_features_per_level == 2
    assert nirc.position.per_level_scale == 1.5 and nirc.position.log2_hashmap_size == 16
    assert nirc.direction.kind == "sh" and nirc.direction.n_features == 25
    assert nirc.normal.kind == "oneblob" and nirc.normal.bins == 4
    assert nirc.roughness.kind == "oneblob" and nirc.albedo and not nirc.albedo_spec
    assert (nirc.mlp.width, nirc.mlp.hidden_layers, nirc.mlp.activation) == (64, 4, "relu")
    assert nirc.loss.kind == "relative_l2" and nirc.optimizer.lr == 1e-2
    assert nirc.ema_decay == 0.99 and nirc.steps_per_frame == 4 and nirc.batch_size == 16384
    assert nirc.n_inputs == 24 + 12 + 4 + 3 + 25

    nrc = caches.nrc_config()
    assert nrc.albedo_spec and nrc.direction.kind == "oneblob" and nrc.mlp.width == 64
    assert nrc.loss.kind == "relative_l2" and nrc.optimizer.lr == 1e-2

    vis = caches.visibility_config(8)
    assert vis.output.n_outputs == 8 and vis.output.activation == "sigmoid"
    assert vis.loss.kind == "l2" and vis.direction.kind == "none"
    assert vis.optimizer.learning_rate_at(mi.UInt32(0))[0] == pytest.approx(0.05)
    assert vis.optimizer.learning_rate_at(mi.UInt32(100))[0] == pytest.approx(0.0255, rel=1e-5)
    assert vis.optimizer.learning_rate_at(mi.UInt32(200))[0] == pytest.approx(1e-3, rel=1e-5)
    assert vis.optimizer.learning_rate_at(mi.UInt32(500))[0] == pytest.approx(1e-3, rel=1e-5)


def test_the_device_learning_rate_schedule_is_the_host_one_bit_for_bit():
    """The schedule read on the device (a frozen step) hands Adam what the Python-float
    schedule did: the linear decay in double precision, rounded once to float32
    (computed in float32 instead, 203 of these 260 steps differ by an ulp)."""
    opt = caches.visibility_config(1).optimizer
    steps = np.arange(260)
    host = np.array([opt.lr + (opt.lr_end - opt.lr) * min(s / opt.lr_decay_steps, 1.0)
                     for s in steps], dtype=np.float32)
    device = np.asarray(opt.learning_rate_at(mi.UInt32(steps)))
    assert device.dtype == np.float32
    np.testing.assert_array_equal(device, host)


def test_config_overrides_deep_merge_and_round_trip_json():
    cfg = caches.nirc_config(direction={"sh_bands": 4}, mlp={"width": 32})
    assert cfg.direction.sh_bands == 4 and cfg.direction.kind == "sh"
    assert cfg.mlp.width == 32 and cfg.mlp.hidden_layers == 4
    text = cfg.to_json()
    assert json.loads(text)["direction"]["sh_bands"] == 4
    assert caches.CacheConfig.from_json(text) == cfg
    with pytest.raises(ValidationError):
        cfg.mlp.width = 16  # frozen: a stored config means one network


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"direction": {"sh_bands": 0}}, "sh_bands must be between 1 and 8"),
        ({"direction": {"sh_bands": 9}}, "sh_bands must be between 1 and 8"),
        ({"ema_decay": 1.0}, "ema_decay must be in (0, 1)"),
        ({"output": {"n_outputs": 2}}, "relative_to='luminance' needs RGB outputs"),
        ({"mlp": {"activation": "tanh"}}, "activation"),
        ({"batch_size": 0}, "batch_size"),
        ({"position": {"per_level_scale": 1.0}}, "per_level_scale"),
        ({"hashgrid": {}}, "unknown cache config field"),
    ],
)
def test_config_validation_explains_errors(overrides, message):
    with pytest.raises((ValidationError, ValueError), match=message.replace("(", r"\(")
                       .replace(")", r"\)")):
        caches.nirc_config(**overrides)


# --------------------------------------------------------------------------
# Encodings
# --------------------------------------------------------------------------

def test_encodings_identical_in_tensor_and_inference_modes():
    rec = synthetic_records(257, seed=3)
    x = rec.roughness
    cases = [
        (enc.OneBlobEncoding(2, 4), (x, 1.0 - x)),
        (enc.IdentityEncoding(3), tuple(rec.albedo)),
        (enc.SHEncoding(5), (rec.direction,)),
        (enc.SphericalOneBlobEncoding(4), (rec.direction,)),
        (enc.PositionEncoding(caches.HashGridConfig(log2_hashmap_size=12), [0, 0, 0],
                              [1, 1, 1], dr.rng(1)), (rec.position,)),
    ]
    for encoding, inputs in cases:
        rows = encoding.encode(*inputs)
        tensor = encoding.tensor(*inputs)
        assert len(rows) == encoding.n_features
        assert tensor.shape == (encoding.n_features, 257)
        np.testing.assert_array_equal(as_numpy(rows), tensor.numpy())


def test_encoding_values():
    # One-blob: the Gaussian mass per bin peaks in the bin containing x.
    x = mi.Float(0.1, 0.6, 0.95)
    blob = as_numpy(enc.one_blob(x, 4))
    assert blob.shape == (4, 3)
    assert list(blob.argmax(axis=0)) == [0, 2, 3]
    assert np.all(blob >= 0) and np.all(blob.sum(axis=0) <= 1.0)
    # SH: B bands give B^2 coefficients, equal to dr.sh_eval of the unit vector.
    d = mi.Vector3f(0.0, 0.6, 0.8)
    sh = enc.SHEncoding(3).encode(d * 2.0)  # renormalised
    ref = dr.sh_eval(d, 2)
    assert len(sh) == 9
    np.testing.assert_allclose(as_numpy(sh), as_numpy(ref), rtol=1e-6, atol=1e-7)
    # Position: the box (with its margin) maps into [0, 1]^3, outside is clamped.
    pos = enc.PositionEncoding(enc.HashGridConfig(bbox_margin=0.25), [-1, 0, 0], [1, 2, 4],
                               dr.rng(0))
    # x: [-1, 1] grown to [-1.5, 1.5]; y: [0, 2] -> [-0.5, 2.5]; z: [0, 4] -> [-1, 5].
    u = as_numpy(pos.normalise(mi.Point3f([-1, 1, 9], [0, 1, 2], [4, 2, 0])))
    np.testing.assert_allclose(u[0], [1 / 6, 5 / 6, 1.0], rtol=1e-6)
    np.testing.assert_allclose(u[1], [1 / 6, 1 / 2, 5 / 6], rtol=1e-6)
    np.testing.assert_allclose(u[2], [5 / 6, 1 / 2, 1 / 6], rtol=1e-6)


def test_records_accept_constants_and_reject_mismatched_widths():
    cache = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1])
    rec = synthetic_records(1024, seed=7)
    rec.roughness = mi.Float(0.3)            # one value for every record
    rec.albedo = mi.Color3f(0.5, 0.4, 0.3)
    assert len(cache.train(rec, steps=2)) == 2
    rec.roughness = dr.full(mi.Float, 0.3, 17)
    with pytest.raises(ValueError, match="'roughness' has width"):
        cache.train(rec, steps=1)
    rec.roughness = mi.Float(0.3)
    rec.target = [mi.Float(1.0)] * 2
    with pytest.raises(ValueError, match="targets have 2 channels"):
        cache.train(rec, steps=1)


def test_reproducible_grid_gradient_equals_drjit_gradient():
    from renderers.caches.grid_grad import grid_lookup

    pos = enc.PositionEncoding(caches.HashGridConfig(n_levels=5, log2_hashmap_size=10,
                                                     base_resolution=4), [0, 0, 0], [1, 1, 1],
                               dr.rng(1))
    rng = dr.rng(3)
    p = [rng.random(mi.Float, 3000) for _ in range(3)]
    weights = [rng.normal(mi.Float, 3000) for _ in range(pos.n_features)]

    def gradient(custom):
        data = mi.Float(pos.grid.data)
        dr.enable_grad(data)
        grid = pos.with_data(data).grid
        out = grid_lookup(grid, p) if custom else grid(p)
        dr.backward(sum(dr.sum(o * w) for o, w in zip(out, weights, strict=True)))
        return np.asarray(dr.grad(data)), as_numpy(out)

    (g_ours, out_ours), (g_ref, out_ref) = gradient(True), gradient(False)
    np.testing.assert_array_equal(out_ours, out_ref)   # same forward values
    np.testing.assert_allclose(g_ours, g_ref, rtol=0, atol=1e-5 * np.abs(g_ref).max())
    assert np.abs(g_ref).max() > 0


def _bias_apart(net, rows):
    """The MLP with each bias a product of its own, ``W @ x + b @ ones(1, N)`` (the
    form the folded ``[W b] @ [x; 1]`` replaced)."""
    from drjit import nn

    x = enc.to_tensor(rows)
    ones = dr.ones(mi.TensorXf, (1, x.shape[1]))
    for layer in net.layers:
        if isinstance(layer, nn.Linear):
            bias = dr.reshape(mi.TensorXf, layer.bias, (layer.bias.shape[0], 1)) @ ones
            x = layer.weights @ x + bias
        else:
            x = layer(x)
    return x


@pytest.mark.parametrize("activation", ["leaky_relu", "relu"])
def test_folded_bias_is_bitwise_the_bias_apart(activation):
    """The training MLP's values and gradients are bit for bit those of the bias as a
    product of its own; planted: Dr.Jit's own layers (the bias broadcast, its gradient
    summed over the batch in another order) differ."""
    from drjit import nn

    from renderers.caches.cache import build_mlp, mlp_forward_tensor

    config = small_config(mlp={"width": 16, "hidden_layers": 2, "activation": activation})
    rng = dr.rng(6)
    n = 1500   # two of the GEMM's 1024-record reduction segments, the second partial
    inputs = [rng.normal(mi.Float, n) for _ in range(7)]
    target = mi.TensorXf(rng.normal(mi.Float, 3 * n), (3, n))

    def run(forward):
        net = build_mlp(config).alloc(mi.TensorXf, 7, rng=dr.rng(5))
        params = [p for layer in net.layers if isinstance(layer, nn.Linear)
                  for p in (layer.weights, layer.bias)]
        rows = [mi.Float(r) for r in inputs]
        for value in (*params, *rows):
            dr.enable_grad(value)
        y = forward(net, [dr.sin(r) for r in rows])
        dr.backward(dr.mean(dr.square(y - target), axis=None))
        return [y.numpy(), *(dr.grad(v).numpy() for v in (*params, *rows))]

    folded, apart = run(mlp_forward_tensor), run(_bias_apart)
    for ours, theirs in zip(folded, apart, strict=True):
        np.testing.assert_array_equal(ours, theirs)
    planted = run(lambda net, rows: net(enc.to_tensor(rows)))
    assert not all(np.array_equal(a, b) for a, b in zip(folded, planted, strict=True))


def test_layer_gradients_check_every_weight_and_bias_but_not_the_row_of_ones():
    from renderers.caches.cache import LayerGradients

    def finite(*matrices):
        gradients = LayerGradients()
        gradients.matrices = [(mi.Float(values), size) for values, size in matrices]
        return bool(gradients.finite()[0])

    wide, narrow = np.arange(12, dtype=np.float32), np.arange(4, dtype=np.float32)
    assert finite((wide, 9), (narrow, 4))
    for at in (0, 8):   # a weight's or a bias's gradient, in the wider matrix
        bad = wide.copy()
        bad[at] = np.nan
        assert not finite((bad, 9), (narrow, 4))
    narrow_bad = narrow.copy()
    narrow_bad[3] = np.inf   # the narrower matrix's last entry
    assert not finite((wide, 9), (narrow_bad, 4))
    ones_row = wide.copy()
    ones_row[10] = np.nan    # the row of ones' gradient: no parameter's
    assert finite((ones_row, 9), (narrow, 4))


def test_folded_bias_refuses_an_activation_that_drops_the_row_of_ones():
    from drjit import nn

    from renderers.caches.cache import mlp_forward_tensor

    net = nn.Sequential(nn.Linear(-1, 4), nn.Tanh(), nn.Linear(-1, 1)).alloc(
        mi.TensorXf, 2, rng=dr.rng(0))
    with pytest.raises(TypeError, match="Tanh"):
        mlp_forward_tensor(net, [mi.Float(0.5), mi.Float(1.0)])


def test_zero_direction_gives_finite_features():
    d = mi.Vector3f(0.0, 0.0, 0.0)
    for encoding in (enc.SHEncoding(4), enc.SphericalOneBlobEncoding(4)):
        assert np.all(np.isfinite(as_numpy(encoding.encode(d))))


def test_missing_input_is_explained():
    cache = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1])
    with pytest.raises(ValueError, match="encodes 'normal' but no normal was given"):
        cache.surface_features(mi.Point3f(0.5, 0.5, 0.5))


# --------------------------------------------------------------------------
# Training
# --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def trained():
    """A small cache trained on the smooth synthetic target."""
    cache = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1], seed=5)
    records = synthetic_records(1 << 14, seed=1)
    initial = cache.evaluate_loss(records)
    for _ in range(100):  # 100 frames of 4 steps
        cache.train(records)
    return cache, records, initial


def test_training_fits_a_smooth_target(trained):
    cache, records, initial = trained
    assert cache.stats["steps"] == 400 and cache.stats["skipped_steps"] == 0
    assert len(cache.loss_history) == 400
    final = cache.evaluate_loss(records)
    assert final < initial / 1000, (initial, final)
    # Held-out points: predictions approach the target.
    test = synthetic_records(4096, seed=99)
    pred = as_numpy(query_records(cache, test))
    target = as_numpy(test.target)
    rel = np.abs(pred - target).mean() / target.mean()
    assert rel < 0.1, rel  # 0.064 measured (relative L2 converges slower than L2)


def test_coopvec_inference_matches_tensor_mode(trained):
    cache, records, _ = trained
    coop = as_numpy(query_records(cache, records))
    tensor = cache.predict_tensor(records).numpy()
    np.testing.assert_allclose(coop, tensor, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("split", [True, False])
def test_half_precision_inference_is_float32_inference_rounded(trained, split):
    """CUDA's cooperative vectors take float16 only: the half-precision network (run
    here on the CPU, which takes both) gives the float32 network's outputs to float16
    rounding; it is not the float32 network unchanged, nor a wrong one."""
    from renderers.caches.inference import PackedMLP, half_precision

    assert half_precision(dr.JitBackend.CUDA) and not half_precision(dr.JitBackend.LLVM)
    cache, records, _ = trained
    rows = cache.encoder.surface(records.position, records.normal, records.roughness,
                                 records.albedo, position_encoding=cache._infer_position)
    direction = cache.encoder.direction(records.direction)
    n_surface = cache.config.n_surface_features

    def outputs(half, network=cache.tensor_network):
        mlp = PackedMLP(network, n_surface, split_first_layer=split, half=half)
        out = mlp.finish(mlp.surface(rows), direction)
        assert all(type(o) is mi.Float for o in out)
        return as_numpy(out)

    full, half = outputs(False), outputs(True)
    scale = np.abs(full).max()
    assert scale > 0.1
    assert not np.array_equal(full, half)  # the weights really were rounded
    np.testing.assert_allclose(half, full, atol=5e-3 * scale)
    # A planted defect the tolerance rejects: one output weight perturbed by 2 %.
    planted = copy.deepcopy(cache.tensor_network)
    last = planted.layers[-1]
    last.weights = last.weights * 1.02
    with pytest.raises(AssertionError):
        np.testing.assert_allclose(outputs(True, planted), full, atol=5e-3 * scale)


@pytest.mark.parametrize("split", [True, False])
def test_a_packed_network_bound_to_other_weights_evaluates_those(trained, split):
    """PackedMLP.arrays() is what a frozen frame takes of the weights (split: the one
    buffer every matrix view reads) and bind() makes a network evaluate another
    network's: bound to a perturbed copy's arrays, the outputs are the copy's, bitwise.
    Planted: a bind that keeps the views (the weights it was packed with)."""
    from renderers.caches.inference import PackedMLP

    cache, records, _ = trained
    rows = cache.encoder.surface(records.position, records.normal, records.roughness,
                                 records.albedo, position_encoding=cache._infer_position)
    direction = cache.encoder.direction(records.direction)
    n_surface = cache.config.n_surface_features
    perturbed = copy.deepcopy(cache.tensor_network)
    perturbed.layers[0].weights = perturbed.layers[0].weights * 1.02
    mine = PackedMLP(cache.tensor_network, n_surface, split_first_layer=split)
    theirs = PackedMLP(perturbed, n_surface, split_first_layer=split)

    def outputs(mlp):
        return as_numpy(mlp.finish(mlp.surface(rows), direction))

    own, expected = outputs(mine), outputs(theirs)
    assert not np.array_equal(own, expected)
    mine.bind(theirs.arrays())
    np.testing.assert_array_equal(outputs(mine), expected)
    if split:   # planted
        kept = PackedMLP(cache.tensor_network, n_surface)
        kept.bind = lambda _arrays: None
        kept.bind(theirs.arrays())
        np.testing.assert_array_equal(outputs(kept), own)


def test_non_finite_targets_are_dropped_and_counted():
    cache = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1], seed=2)
    rec = synthetic_records(4096, seed=4)
    target = as_numpy(rec.target)
    target[0, :10] = np.nan
    target[1, 5:15] = np.inf      # overlaps lanes 5..9: lanes 0..14 are bad
    target[2, 100] = -np.inf      # ... and lane 100: 16 in total
    target[:, 250] = np.nan       # an invalid record: counted as invalid only
    rec.target = mi.Color3f(*target)
    position = as_numpy(rec.position)
    position[0, [7, 400, 401]] = np.nan   # lane 7's target is bad: counted there only
    rec.position = mi.Point3f(*position)
    valid = np.ones(4096, dtype=bool)
    valid[200:300] = False
    rec.valid = mi.Bool(valid)
    losses = cache.train(rec, steps=4)
    assert cache.stats["dropped_nonfinite_targets"] == 16
    assert cache.stats["dropped_invalid"] == 100
    assert cache.stats["dropped_nonfinite_inputs"] == 2
    assert cache.stats["records_seen"] == 4096 - 118
    assert len(losses) == 4 and np.all(np.isfinite(losses))
    for values in (*cache.parameters().values(), *cache.inference_parameters().values()):
        assert np.all(np.isfinite(values))


def test_non_finite_step_is_skipped_and_weights_unchanged():
    cache = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1], seed=2)
    rec = synthetic_records(2048, seed=4)
    cache.train(rec, steps=2)
    before = cache.parameters()
    # Finite targets so large that the squared error overflows float32: the
    # loss and its gradients are non-finite, the step must not be taken.
    rec.target = mi.Color3f(*[dr.full(mi.Float, 1e30, 2048)] * 3)
    losses = cache.train(rec, steps=3)
    assert losses == []
    assert cache.stats["skipped_steps"] == 3 and cache.stats["steps"] == 2
    assert cache.stats["dropped_nonfinite_targets"] == 0
    after = cache.parameters()
    for key, value in before.items():
        np.testing.assert_array_equal(value, after[key])
    # Training continues normally afterwards.
    rec.target = smooth_target(rec.position, rec.direction)
    assert len(cache.train(rec, steps=1)) == 1


def test_ema_weights_are_used_for_inference():
    rec = synthetic_records(2048, seed=6)
    cache = caches.NeuralCache(small_config(ema_decay=0.5), [0, 0, 0], [1, 1, 1])
    cache.train(rec, steps=1)
    w1 = cache.parameters()
    # One step: the debiased EMA equals the weights.
    for key, value in cache.inference_parameters().items():
        np.testing.assert_allclose(value, w1[key], rtol=1e-6, atol=1e-9)
    cache.train(rec, steps=1)
    w2 = cache.parameters()
    # Two steps, decay 1/2: (0.25 w1 + 0.5 w2) / (1 - 0.25) = (w1 + 2 w2) / 3.
    for key, value in cache.inference_parameters().items():
        np.testing.assert_allclose(value, (w1[key] + 2 * w2[key]) / 3, rtol=1e-5, atol=1e-7)
    assert not np.allclose(cache.inference_parameters()["mlp.layers.0.weights"],
                           w2["mlp.layers.0.weights"])
    # ... and the network queried for rendering is the EMA one.
    no_ema = caches.NeuralCache(small_config(ema_decay=None), [0, 0, 0], [1, 1, 1])
    no_ema.train(rec, steps=2)
    for key, value in no_ema.inference_parameters().items():
        np.testing.assert_array_equal(value, no_ema.parameters()[key])
    np.testing.assert_allclose(no_ema.parameters()["mlp.layers.0.weights"],
                               w2["mlp.layers.0.weights"], rtol=1e-5, atol=1e-7)
    assert not np.allclose(as_numpy(query_records(cache, rec)),
                           as_numpy(query_records(no_ema, rec)))


def test_seed_determines_everything():
    rec = synthetic_records(4096, seed=8)

    def run(seed):
        cache = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1], seed=seed)
        losses = cache.train(rec, steps=3, batch_size=1024)
        return losses, as_numpy(query_records(cache, rec))

    losses_a, pred_a = run(11)
    losses_b, pred_b = run(11)
    losses_c, pred_c = run(12)
    assert losses_a == losses_b
    np.testing.assert_array_equal(pred_a, pred_b)
    assert not np.allclose(pred_a, pred_c)


def test_float_atomic_grid_gradient_option_trains_alike():
    rec = synthetic_records(4096, seed=9)
    ours = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1], seed=3)
    atomic = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1], seed=3,
                                deterministic=False)
    losses_ours, losses_atomic = ours.train(rec, steps=4), atomic.train(rec, steps=4)
    np.testing.assert_allclose(losses_ours, losses_atomic, rtol=1e-3)
    np.testing.assert_allclose(ours.parameters()["position.hashgrid"],
                               atomic.parameters()["position.hashgrid"], rtol=0, atol=1e-4)
    assert atomic.describe()["deterministic"] is False


def tiny_visibility_config(**optimizer):
    """A two-light visibility cache small enough to train a few steps in a test."""
    return caches.visibility_config(2, position={"n_levels": 4, "log2_hashmap_size": 10},
                                    batch_size=1024, optimizer=optimizer)


def visibility_records():
    """4096 fixed points in the unit box, each light seen from one side of a plane."""
    rng = dr.rng(7)
    n = 4096
    p = mi.Point3f(rng.random(mi.Float, n), rng.random(mi.Float, n), rng.random(mi.Float, n))
    return caches.TrainingRecords(position=p, target=[dr.select(p.x > 0.4, 1.0, 0.0),
                                                      dr.select(p.y + p.z > 1.0, 1.0, 0.0)])


@pytest.mark.parametrize("frozen", [True, False])
def test_a_learning_rate_on_the_device_steps_like_a_float_one(frozen):
    """A schedule from lr to the same lr is the float lr as a Dr.Jit value: training
    must be identical bit for bit. Dr.Jit's Adam scales an array-valued learning rate
    in place by each parameter's debiasing factor; unguarded, every parameter after
    the first stepped with a power of that factor (every second one uphill)."""
    from renderers.frozen import frozen_frames

    records = visibility_records()

    def train(**optimizer):
        with frozen_frames(frozen):
            cache = caches.NeuralCache(tiny_visibility_config(lr=0.02, **optimizer),
                                       [0, 0, 0], [1, 1, 1], seed=3)
        for _ in range(3):
            cache.train(records, steps=2)
        return cache

    constant = train(lr_decay_steps=0)  # the preset's decay off: a float lr
    scheduled = train(lr_end=0.02, lr_decay_steps=4)
    assert constant.config.optimizer.learning_rate_at(mi.UInt32(0)) == 0.02
    assert isinstance(scheduled.config.optimizer.learning_rate_at(mi.UInt32(0)), mi.Float)
    assert scheduled.loss_history == constant.loss_history
    for key, value in constant.parameters().items():
        np.testing.assert_array_equal(scheduled.parameters()[key], value, err_msg=key)


#: A visibility cache's training on fixed records (tiny_visibility_config with lr 0.05
#: decaying to 0.001 over 4 steps, seed 3, visibility_records, 3 frames of 2 steps)
#: recorded with the training step that preceded the frozen one (traced, the learning
#: rate a Python float from the host's step count, commit e985a9c): the loss of every
#: step and the L2 norm of every parameter afterwards.
RECORDED_LOSSES = [0.25, 0.249101013, 0.245848745, 0.243536994, 0.242098987, 0.242246762]
RECORDED_NORMS = {"mlp.layers.0.weights": 2.58374059, "mlp.layers.0.bias": 0.433809073,
                  "mlp.layers.2.weights": 3.44576941, "mlp.layers.2.bias": 0.409512267,
                  "mlp.layers.4.weights": 3.47243737, "mlp.layers.4.bias": 0.0863814686,
                  "position.hashgrid": 10.5000707}


def test_a_decaying_learning_rate_trains_as_it_did_before_the_step_was_frozen():
    """Same loss curve and weights as the recorded training (tolerances for another
    CPU's summation order; the in-place scaled learning rate gave losses rising to
    0.257 and a hash grid of norm 6.73)."""
    cache = caches.NeuralCache(tiny_visibility_config(lr_decay_steps=4), [0, 0, 0],
                               [1, 1, 1], seed=3)
    assert cache.config.optimizer.lr_end == 1e-3 and cache.config.optimizer.lr == 0.05
    records = visibility_records()
    for _ in range(3):
        cache.train(records, steps=2)
    assert cache.stats["steps"] == 6 and cache.stats["skipped_steps"] == 0
    np.testing.assert_allclose(cache.loss_history, RECORDED_LOSSES, rtol=1e-4)
    norms = {key: np.linalg.norm(value.astype(np.float64))
             for key, value in cache.parameters().items()}
    assert norms.keys() == RECORDED_NORMS.keys()
    for key, norm in RECORDED_NORMS.items():
        assert norms[key] == pytest.approx(norm, rel=1e-3), key


def test_describe_reports_sizes():
    cache = caches.NeuralCache(caches.nirc_config(), [0, 0, 0], [1, 1, 1])
    info = cache.describe()
    assert info["n_inputs"] == 68 and info["n_surface_features"] == 43
    assert info["mlp_layers"] == [[68, 64], [64, 64], [64, 64], [64, 64], [64, 3]]
    assert info["mlp_params"] == 68 * 64 + 3 * (64 * 64 + 64) + 64 + 64 * 3 + 3
    assert 0 < info["hashgrid_params"] <= 12 * 2 * 2**16
    json.dumps(info)  # storable


def test_visibility_cache_outputs_per_light():
    cache = caches.NeuralCache(caches.visibility_config(5, position={"log2_hashmap_size": 12}),
                               [0, 0, 0], [1, 1, 1])
    rng = dr.rng(4)
    n = 4096
    p = mi.Point3f(rng.random(mi.Float, n), rng.random(mi.Float, n), rng.random(mi.Float, n))
    target = [mi.Float(dr.select(p.x > 0.2 * i, 1.0, 0.0)) for i in range(5)]
    rec = caches.TrainingRecords(position=p, target=target)
    losses = cache.train(rec, steps=60)
    assert losses[-1] < losses[0] / 3
    out = cache.query(cache.surface_features(p))
    assert isinstance(out, list) and len(out) == 5
    vis = as_numpy(out)
    assert np.all((vis >= 0) & (vis <= 1))


# --------------------------------------------------------------------------
# Inference inside a Mitsuba integrator (symbolic loop), sharing
# --------------------------------------------------------------------------

#: Fixed offsets added to the normal to make the N_c = 3 query directions.
OFFSETS = [(0.3, 0.1, 0.2), (-0.2, 0.4, 0.1), (0.1, -0.3, -0.2)]
BOUNCE = (0.2, 0.1, 0.3)


def _probe_integrator(cache):
    class CacheProbe(mi.SamplingIntegrator):
        """Sums N_c cache queries at the first two vertices of a deterministic path."""

        def __init__(self, props, cache):
            super().__init__(props)
            self.cache = cache

        # @dr.syntax re-executes the rewritten source with the module's
        # globals: reach the cache through `self`, not a closure.
        @dr.syntax
        def sample(self, scene, sampler, ray, medium=None, active=True):
            ray = mi.Ray3f(ray)
            L = mi.Color3f(0)          # sum of cache queries
            depth = mi.UInt32(0)       # vertices visited
            active = mi.Bool(active)   # active SIMD lanes
            while dr.hint(active, max_iterations=-1):
                si = scene.ray_intersect(ray, active)
                hit = active & si.is_valid()
                surface = self.cache.surface_features(si.p, si.n, mi.Float(0.3),
                                                      mi.Color3f(0.5))
                for offset in OFFSETS:
                    d = dr.normalize(si.n + mi.Vector3f(offset))
                    L += dr.select(hit, self.cache.query(surface, d), 0)
                ray = si.spawn_ray(dr.normalize(si.n + mi.Vector3f(BOUNCE)))
                depth += 1
                active = hit & (depth < 2)
            return L, mi.Bool(True), []

    return CacheProbe(mi.Properties(), cache)


@pytest.fixture(scope="module")
def cornell():
    scene = mi.load_dict(mi.cornell_box())
    bbox = scene.bbox()
    cache = caches.NeuralCache(small_config(), bbox.min, bbox.max, seed=1)
    # A few steps on a smooth target inside the box so that outputs are non-trivial.
    rng = dr.rng(0)
    n = 4096
    u = [rng.random(mi.Float, n) for _ in range(3)]
    p = mi.Point3f(*[dr.lerp(bbox.min[i], bbox.max[i], u[i]) for i in range(3)])
    d = dr.normalize(mi.Vector3f(rng.normal(mi.Float, n), rng.normal(mi.Float, n),
                                 rng.normal(mi.Float, n)))
    rec = caches.TrainingRecords(position=p, target=smooth_target(mi.Point3f(u), d),
                                 normal=d, roughness=dr.full(mi.Float, 0.3, n),
                                 albedo=dr.full(mi.Color3f, 0.5, n), direction=d)
    cache.train(rec, steps=20)
    return scene, cache


def test_query_inside_symbolic_integrator_loop_equals_outside(cornell):
    scene, cache = cornell
    n = 2048
    rng = dr.rng(2)
    d = dr.normalize(mi.Vector3f(rng.normal(mi.Float, n), rng.normal(mi.Float, n),
                                 rng.normal(mi.Float, n)))
    ray = mi.Ray3f(mi.Point3f(0, 0, 0), d)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(0, n)
    inside, _, _ = _probe_integrator(cache).sample(
        scene, sampler, mi.RayDifferential3f(ray))
    dr.eval(inside)

    # The same path, evaluated step by step outside any loop.
    outside = mi.Color3f(0)
    alive = mi.Bool(True)
    for _ in range(2):
        si = scene.ray_intersect(ray, alive)
        hit = alive & si.is_valid()
        surface = cache.surface_features(si.p, si.n, mi.Float(0.3), mi.Color3f(0.5))
        dr.eval(surface)
        for offset in OFFSETS:
            q = cache.query(surface, dr.normalize(si.n + mi.Vector3f(offset)))
            outside += dr.select(hit, q, 0)
        dr.eval(outside)
        ray = si.spawn_ray(dr.normalize(si.n + mi.Vector3f(BOUNCE)))
        alive = hit
    a, b = as_numpy(inside), as_numpy(outside)
    assert np.all(np.isfinite(a)) and a.max() > 0
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)


def test_integrator_renders_through_mitsuba(cornell):
    scene, cache = cornell
    image = mi.render(scene, integrator=_probe_integrator(cache), spp=1)
    values = np.asarray(image)
    assert values.shape[-1] == 3 and np.all(np.isfinite(values)) and values.max() > 0


def test_shared_surface_features_equal_unshared_queries(trained):
    cache, records, _ = trained
    rec = synthetic_records(1024, seed=12)
    surface = cache.surface_features(rec.position, rec.normal, rec.roughness, rec.albedo)
    for k in range(3):
        d = dr.normalize(rec.direction + mi.Vector3f(0.2 * k, -0.1 * k, 0.05))
        shared = as_numpy(cache.query(surface, d))
        unshared = as_numpy(cache.query_unshared(rec.position, rec.normal, rec.roughness,
                                                 rec.albedo, d))
        np.testing.assert_array_equal(shared, unshared)


def test_first_layer_split_matches_the_concatenated_network():
    rec = synthetic_records(2048, seed=13)
    split = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1], seed=4)
    concat = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1], seed=4,
                                split_first_layer=False)
    split.train(rec, steps=5)
    concat.train(rec, steps=5)
    for key, value in split.parameters().items():  # training does not depend on the split
        np.testing.assert_array_equal(value, concat.parameters()[key])
    a, b = as_numpy(query_records(split, rec)), as_numpy(query_records(concat, rec))
    assert a.max() > 0
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
    assert len(split.surface_features(rec.position, rec.normal, rec.roughness,
                                      rec.albedo)) == split.config.mlp.width
    with pytest.raises(ValueError, match="pass what surface_features"):
        split.query(split.encoder.surface(rec.position, rec.normal, rec.roughness, rec.albedo),
                    rec.direction)


def test_loaded_weights_reproduce_the_trained_cache(trained):
    cache, records, _ = trained
    copy = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1], seed=123)
    before = as_numpy(query_records(copy, records))
    copy.load_inference_parameters(cache.inference_parameters())
    after = as_numpy(query_records(copy, records))
    expected = as_numpy(query_records(cache, records))
    assert np.abs(expected).mean() > 0.01  # a trained, non-trivial cache
    assert not np.array_equal(before, expected)
    np.testing.assert_array_equal(after, expected)
    with pytest.raises(ValueError, match="values"):
        bad = {k: v[:-1] for k, v in cache.inference_parameters().items()}
        copy.load_inference_parameters(bad)
    with pytest.raises(ValueError, match="names"):
        copy.load_inference_parameters({"nonsense": np.zeros(3)})


def test_nonfinite_weights_are_counted_for_the_run(mi):
    """A run's ``cache_stats.nonfinite_weights`` (the stress suite's check that no NaN
    reaches stored weights) counts NaN and infinite entries of the inference weights."""
    import numpy as np

    from renderers.methods.cached import nonfinite_weights

    cache = caches.NeuralCache(small_config(), [0, 0, 0], [1, 1, 1], seed=0)
    assert nonfinite_weights(cache) == 0
    weights = cache.inference_parameters()
    key = next(iter(weights))
    weights[key] = weights[key].copy()
    weights[key][:3] = [np.nan, np.inf, -np.inf]
    cache.load_inference_parameters(weights)
    assert nonfinite_weights(cache) == 3
