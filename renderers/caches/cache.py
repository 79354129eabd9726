"""One neural cache for every method: NRC, NIRC and the visibility caches.

A :class:`NeuralCache` is an input encoder (hash grid + per-surface inputs +
direction, :mod:`renderers.caches.encodings`) followed by an MLP, trained
online with Adam on :class:`TrainingRecords` and queried by the renderer. The
methods differ only by their :class:`~renderers.caches.config.CacheConfig`.

Two copies of the MLP exist, for the two jobs (docs/design.md, "Neural caches
on this CPU"):

- training, in tensor mode: an unpacked ``nn.Sequential`` of ``nn.Linear``
  over a ``TensorXf`` of shape (features, batch), ~4x faster on the CPU than
  backpropagating through a packed CoopVec network. Adam owns the MLP weights
  and the hash-grid table; the network and the grid are rebound to Adam's
  values before every step.
- inference, with cooperative vectors: after each :meth:`NeuralCache.train`
  the (EMA) weights are packed with ``nn.pack(..., layout='inference')`` and
  evaluated on ``nn.CoopVec`` inputs (:class:`~renderers.caches.inference.PackedMLP`),
  which runs on evaluated arrays and inside the symbolic ``@dr.syntax``
  loops of Mitsuba integrators.

Sharing (NIRC paper Sec. 4.5): :meth:`NeuralCache.surface_features` encodes
what does not depend on the direction (hash grid, normal, roughness, albedo)
once per shading point and, by default, also pushes it through the surface
columns of the first layer; :meth:`NeuralCache.query` then costs one direction
encoding + the rest of the MLP per direction. On the 2-core CPU the MLP, not
the hash grid (~0.1-0.16 us), dominates a query, so the first-layer split is
what makes N_c samples much cheaper than N_c single queries.

Reproducibility: the MLP init, the hash-grid init and the batch selection are
all derived from ``seed`` (and, for batches, the optimizer step counter).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np
from drjit import nn
from drjit.opt import Adam

from renderers.caches.config import CacheConfig
from renderers.caches.encodings import InputEncoder, PositionEncoding, Vec3, to_tensor
from renderers.caches.inference import PackedMLP
from renderers.caches.losses import cache_loss
from renderers.caches.records import TrainingRecords
from renderers.caches.screen import ScreenLatentEncoding, ScreenProjection
from renderers.frozen import Frozen, freezing, weak_method
from renderers.seeding import derive_seed

#: Optimizer key of the hash-grid table (the MLP keys are 'mlp.layers.<i>.*').
GRID_KEY = "position.hashgrid"


def build_mlp(config: CacheConfig) -> nn.Sequential:
    """The (unallocated) MLP a config describes; hidden layers + linear output."""
    layers: list[nn.Module] = []
    for _ in range(config.mlp.hidden_layers):
        layers.append(nn.Linear(-1, config.mlp.width))
        if config.mlp.activation == "relu":
            layers.append(nn.ReLU())
        else:
            layers.append(nn.LeakyReLU(config.mlp.leaky_slope))
    layers.append(nn.Linear(-1, config.output.n_outputs))
    return nn.Sequential(*layers, prefix="mlp")


def mlp_forward_tensor(net: nn.Sequential, rows: Sequence[mi.Float],
                       gradients: LayerGradients | None = None) -> mi.TensorXf:
    """Tensor-mode forward pass of an unpacked MLP on feature ``rows`` (each of width N
    or 1: ``to_tensor``), with reproducible gradients; (outputs, N). ``gradients``
    collects the layers' gradients in the backward pass (:class:`LayerGradients`).

    Same as ``net(to_tensor(rows))`` except for the bias: ``nn.Linear`` broadcasts it
    over the batch, whose reverse-mode derivative is a float atomic scatter-add
    (run-dependent summation order on a multi-core CPU). Here each layer is one
    matrix product of its weights and bias ``[W b]`` with its input and a row of ones
    ``[x; 1]``, so the bias's derivative is a column of the weights' (a product, which
    sums in a fixed order). Each product over the batch is 2 kernel launches per 1024
    records on the LLVM backend (Dr.Jit's GEMM reduces K in segments of 1024), so a
    bias of its own, ``b @ ones(1, N)`` added to ``W @ x``, doubled the launches of
    the backward pass. The values are bitwise those of that form: the bias is the
    last term of each output's sum, ``acc + b * 1`` (``tests/renderers/test_caches.py``).

    The row of ones travels through the hidden layers: each hidden layer's matrix has
    a last row ``[0 ... 0 1]``, whose output 1 the activation keeps (ReLU and leaky
    ReLU are the identity at 1).
    """
    x = to_tensor([*rows, mi.Float(1.0)])
    dr.eval(x)
    linears = [layer for layer in net.layers if isinstance(layer, nn.Linear)]
    for layer in net.layers:
        if isinstance(layer, nn.Linear):
            matrix = dr.custom(_WithBias, layer.weights, layer.bias,
                               layer is not linears[-1], gradients)
            x = matrix @ x
        elif isinstance(layer, nn.ReLU | nn.LeakyReLU):
            x = layer(x)
        else:
            raise TypeError(f"{type(layer).__name__} does not keep the row of ones")
    return x


class LayerGradients:
    """The gradients of a training MLP's matrices ``[W b]`` (:func:`mlp_forward_tensor`),
    as its backward pass computes them: :meth:`finite` checks every weight and bias in one
    kernel (a check per parameter was a kernel and a reduction each)."""

    def __init__(self) -> None:
        #: (the gradient of a layer's matrix, flat, and how many of its first entries
        #: are those of ``[W b]``: the rest are the row of ones').
        self.matrices: list[tuple[mi.Float, int]] = []

    def finite(self) -> mi.Bool:
        """Whether every collected gradient of a weight or a bias is finite (width 1)."""
        lane = dr.arange(mi.UInt32, max(dr.width(grad) for grad, _ in self.matrices))
        finite = mi.Bool(True)
        for grad, size in self.matrices:
            inside = lane < size
            finite &= ~inside | dr.isfinite(dr.gather(mi.Float, grad, lane, inside))
        return dr.all(finite)


class _WithBias(dr.CustomOp):
    """``[W b]`` of a layer, and below it, with ``ones_row``, the row ``[0 ... 0 1]``
    that carries the input's row of ones to the output (:func:`mlp_forward_tensor`): one
    kernel of gathers. Backward: W's and b's gradients are the matching entries of the
    matrix's gradient, gathered where they are read (the optimizer's kernels)."""

    def eval(self, weights: mi.TensorXf, bias: mi.TensorXf, ones_row: bool,
             gradients: LayerGradients | None) -> mi.TensorXf:
        self.gradients = gradients
        self.shape = outputs, inputs = weights.shape
        row, column = _entries(outputs + ones_row, inputs + 1)
        weight = dr.gather(mi.Float, weights.array, row * inputs + column,
                           (row < outputs) & (column < inputs))
        below = dr.select(row < outputs, dr.gather(mi.Float, bias.array, row, row < outputs),
                          1.0)
        return mi.TensorXf(dr.select(column < inputs, weight, below),
                           (outputs + ones_row, inputs + 1))

    def forward(self) -> None:
        raise NotImplementedError("forward-mode derivatives of the MLP are not needed")

    def backward(self) -> None:
        grad = self.grad_out().array
        outputs, inputs = self.shape
        if self.gradients is not None:
            self.gradients.matrices.append((grad, outputs * (inputs + 1)))
        row, column = _entries(outputs, inputs)
        self.set_grad_in("weights", mi.TensorXf(
            dr.gather(mi.Float, grad, row * (inputs + 1) + column), (outputs, inputs)))
        self.set_grad_in("bias", mi.TensorXf(
            dr.gather(mi.Float, grad, dr.arange(mi.UInt32, outputs) * (inputs + 1) + inputs),
            (outputs,)))

    def name(self) -> str:
        return "WithBias"


def _entries(rows: int, columns: int) -> tuple[mi.UInt32, mi.UInt32]:
    """(row, column) of each entry of a row-major ``rows`` x ``columns`` matrix."""
    at = dr.arange(mi.UInt32, rows * columns)
    return at // columns, at % columns


def sigmoid(x: Any) -> Any:
    """Logistic function; works on Floats and tensors alike."""
    return dr.rcp(1.0 + dr.exp(-x))


class ScheduledAdam(Adam):
    """Dr.Jit's Adam whose learning rate may be a Dr.Jit array (the schedule read on the
    device, :meth:`~renderers.caches.config.OptimizerConfig.learning_rate_at`).

    Dr.Jit 1.5.0's ``Adam._step`` scales each parameter's step by
    ``_LRCache.product(lr, f_t)``, f_t = -sqrt(1 - b2^t) / (1 - b1^t) the moments'
    debiasing [Kingma & Ba, Alg. 1], and that product multiplies an array-valued
    ``lr`` *in place* (``scale_o *= arg``). With one learning-rate array for all
    parameters, the k-th parameter of a step then moved with lr f_t^k instead of
    lr f_t: every second one uphill, and a visibility cache's hash grid (the 7th) at
    f_t^6 of its rate (b 0.9/0.99: 0.17 at step 2, 0.011 at step 10, 0.65 at 200).
    Each parameter's step here gets its own copy of the array, which takes the
    factor; a float ``lr`` is folded into a constant and never was scaled in place.
    """

    def _step(self, cache: Any, value: Any, grad: Any, lr: Any, extra: Any, /) -> Any:
        if isinstance(lr, dr.ArrayBase):
            lr = type(lr)(lr)
        return super()._step(cache, value, grad, lr, extra)


def _scaled(value: Any, factor: mi.Float) -> Any:
    """``value * factor`` for a Float or a tensor, ``factor`` a width-1 Float."""
    if dr.is_tensor_v(value):
        return type(value)(value.array * factor, value.shape)
    return value * factor


class NeuralCache:
    """A neural radiance / visibility cache (see module docstring).

    Args:
        config: the network, its inputs and its training (stored with runs).
        bbox_min, bbox_max: the scene's bounding box (e.g.
            ``scene.bbox().min``); positions are normalised by it.
        seed: determines the weight init, hash-grid init and batch selection.
        split_first_layer: share the surface part of the first layer across
            directions (default; see :mod:`renderers.caches.inference`).
            False concatenates the inputs instead (benchmark comparison).
            Outputs agree up to float summation order. The split costs ~10 %
            for a single direction (NRC, N_c = 1) and saves 1.2-1.7x from
            N_c = 2 on (measured, benchmarks/bench_cache.py).
        deterministic: bit-reproducible hash-grid gradients (default;
            :mod:`renderers.caches.grid_grad`; cost within run-to-run noise,
            0-17 % of a training step measured); False uses Dr.Jit's float
            atomics, whose summation order varies between runs on a
            multi-core CPU.
        screen: the camera's projection, for a config with screen-space latent
            features (SS NIRC, :mod:`renderers.caches.screen`), whose table then
            stands where the hash grid does (``hashgrid_*`` of :meth:`describe`).

    Attributes:
        loss_history: loss of every optimizer step taken, in order.
        stats: counters — ``records_seen`` (usable records given to
            :meth:`train`), ``dropped_invalid`` (``valid`` False),
            ``dropped_nonfinite_targets``, ``dropped_nonfinite_inputs``,
            ``steps`` (steps taken), ``records_trained`` (records in the
            batches of the steps taken), ``skipped_steps`` (steps whose loss
            or gradients were non-finite: weights left unchanged),
            ``reduced_frames`` (calls of :meth:`train` that took fewer steps
            because ``config.converged_training`` judged the loss converged).
        frame_loss_ema: the converged-training rule's moving average of the
            loss after every :meth:`train` call that took steps (empty when
            the rule is off).
    """

    def __init__(self, config: CacheConfig, bbox_min: Vec3, bbox_max: Vec3,
                 seed: int = 0, split_first_layer: bool = True,
                 deterministic: bool = True, screen: ScreenProjection | None = None) -> None:
        self.config = config
        self.seed = int(seed)
        self.split_first_layer = bool(split_first_layer)
        self.deterministic = bool(deterministic)
        self.bbox_min = [float(v) for v in bbox_min]
        self.bbox_max = [float(v) for v in bbox_max]

        # ---- Inputs and network, initialised from the seed ----
        self.encoder = InputEncoder(config, self.bbox_min, self.bbox_max,
                                    dr.rng(derive_seed(self.seed, "hashgrid")), screen)
        self.encoder.position.deterministic_grad = self.deterministic
        arch = build_mlp(config)
        self._net = arch.alloc(mi.TensorXf, config.n_inputs,
                               rng=dr.rng(derive_seed(self.seed, "mlp")))
        # Unpacked holder of the inference weights: packed after each train()
        # and used directly for tensor-mode inference (benchmarks, tests).
        self._infer_src = arch.alloc(mi.TensorXf, config.n_inputs, rng=dr.rng(0))
        self._mlp_keys = list(self._net.keys())

        # ---- Optimizer: owns the MLP weights and the hash-grid table ----
        o = config.optimizer
        self._opt = ScheduledAdam(lr=o.lr, beta_1=o.beta1, beta_2=o.beta2, epsilon=o.eps)
        for key in self._mlp_keys:
            self._opt[key] = self._net[key]
        self._opt[GRID_KEY] = self.encoder.position.data
        self._keys = [*self._mlp_keys, GRID_KEY]

        # ---- Exponential moving average of the weights (inference) ----
        self._ema: dict[str, Any] | None = None
        if config.ema_decay is not None:
            self._ema = {k: dr.zeros(type(v), v.shape) for k, v in self._params().items()}
        self._ema_steps = 0

        self._attempted_steps = 0     # steps tried, also seeds the batch draws
        # Steps taken, on the device: the learning-rate schedule reads it inside a step.
        self._counters = {"steps": mi.UInt32(0)}
        self._last_step: tuple[TrainingRecords, mi.UInt32] | None = None  # for settle()
        # The training step, frozen (renderers.frozen) when frames are frozen.
        self._step_fn = (Frozen(weak_method(self._train_step), auto_opaque=False)
                         if freezing() else self._train_step)
        self.loss_history: list[float] = []
        self.stats: dict[str, int] = {
            "records_seen": 0,
            "dropped_invalid": 0,
            "dropped_nonfinite_targets": 0,
            "dropped_nonfinite_inputs": 0,
            "steps": 0,
            "records_trained": 0,
            "skipped_steps": 0,
            "reduced_frames": 0,
        }
        self.frame_loss_ema: list[float] = []
        self._refresh_inference()

    # ------------------------------------------------------------------
    # Sizes and description
    # ------------------------------------------------------------------
    @property
    def n_outputs(self) -> int:
        return self.config.output.n_outputs

    @property
    def n_inputs(self) -> int:
        return self.config.n_inputs

    def describe(self) -> dict[str, Any]:
        """What is stored with a run besides the config: sizes and progress."""
        layers = [list(layer.config[:2]) for layer in self._net.layers
                  if isinstance(layer, nn.Linear)]
        mlp_params = sum(i * o + o for i, o in layers)
        grid_params = self.encoder.position.n_params
        return {
            "seed": self.seed,
            "bbox_min": self.bbox_min,
            "bbox_max": self.bbox_max,
            "n_inputs": self.n_inputs,
            "n_surface_features": self.config.n_surface_features,
            "n_direction_features": self.config.direction.n_features,
            "n_outputs": self.n_outputs,
            "mlp_layers": layers,
            "mlp_params": mlp_params,
            "hashgrid_params": grid_params,
            "hashgrid_resolutions": self.encoder.position.resolutions(),
            "total_params": mlp_params + grid_params,
            "split_first_layer": self.split_first_layer,
            "deterministic": self.deterministic,
            "optimizer_steps": self.stats["steps"],
            "ema_steps": self._ema_steps,
            "stats": dict(self.stats),
            "config": self.config.model_dump(mode="json"),
        }

    # ------------------------------------------------------------------
    # Inference
    # ------------------------------------------------------------------
    @property
    def inference_network(self) -> PackedMLP:
        """The packed network :meth:`query` evaluates (refreshed by :meth:`train`)."""
        return self._infer

    @property
    def tensor_network(self) -> nn.Sequential:
        """The inference weights as an unpacked tensor-mode network."""
        return self._infer_src

    def recordings(self) -> int | None:
        """Recordings of the frozen training step (None when it is not frozen)."""
        return self._step_fn.recordings() if isinstance(self._step_fn, Frozen) else None

    def settle(self) -> None:
        """Run the frozen training step once more on the last step's records but on a
        copy of the optimizer, EMA and counter, so that its recordings settle in a
        warm-up without training the cache any further."""
        if self.recordings() is None or self._last_step is None:
            return
        opt = copy.copy(self._opt)
        opt.state, opt.lr = _fresh(self._opt.state), _fresh(self._opt.lr)
        _detach_weights(opt)
        dr.eval(self._step_fn(opt, _fresh(self._ema or {}), _fresh(self._counters),
                              *self._last_step))

    def inference_state(self) -> dict[str, Any]:
        """The Dr.Jit arrays inference reads (packed weights, hash-grid table), changed
        by every training step: a frozen frame takes them as an argument and
        :meth:`bind_inference` s them (renderers.frozen)."""
        return {"mlp": self._infer.arrays(), "grid": self._infer_position.data}

    def bind_inference(self, state: dict[str, Any]) -> None:
        """Infer with ``state`` (:meth:`inference_state`)."""
        self._infer.bind(state["mlp"])
        self._infer_position = self._infer_position.with_data(state["grid"])

    @property
    def n_surface_values(self) -> int:
        """Length of the list :meth:`surface_features` returns."""
        if self.split_first_layer:
            return self.config.mlp.width
        return self.config.n_surface_features

    def surface_features(self, position: Vec3, normal: Vec3 | None = None,
                         roughness: mi.Float | None = None, albedo: Vec3 | None = None,
                         albedo_spec: Vec3 | None = None) -> list[mi.Float]:
        """Everything about a shading point that does not depend on the direction.

        Computed once per shading point and shared by all directions queried
        there (NIRC paper Sec. 4.5): the input encodings (hash grid, normal,
        roughness, albedos) and, with ``split_first_layer``, their product
        with the first layer's surface columns plus its bias. Treat the list
        (``n_surface_values`` Floats) as opaque: pass it to :meth:`query`.
        Inputs the config does not use may be None.
        """
        rows = self.encoder.surface(position, normal, roughness, albedo, albedo_spec,
                                    position_encoding=self._infer_position)
        return self._infer.surface(rows)

    def query_outputs(self, surface: Sequence[mi.Float],
                      direction: Vec3 | None = None) -> list[mi.Float]:
        """Network outputs for ``surface`` (from :meth:`surface_features`) and
        one direction, as a list of ``n_outputs`` Floats.

        Output activation applied: clamped at >= 0 (``clamped_linear``) or
        sigmoid. Works on evaluated arrays and inside symbolic loops.
        """
        if len(surface) != self.n_surface_values:
            raise ValueError(f"surface has {len(surface)} values, expected "
                             f"{self.n_surface_values}: pass what surface_features() returned")
        out = self._infer.finish(list(surface), self.encoder.direction(direction))
        if self.config.output.activation == "sigmoid":
            return [sigmoid(o) for o in out]
        return [dr.maximum(o, 0.0) for o in out]

    def query(self, surface: Sequence[mi.Float],
              direction: Vec3 | None = None) -> mi.Color3f | list[mi.Float]:
        """Cached value for ``surface`` and ``direction``.

        Returns ``mi.Color3f`` when the cache has 3 outputs (radiance caches),
        otherwise the list of ``n_outputs`` Floats (e.g. per-light visibility).
        """
        out = self.query_outputs(surface, direction)
        return mi.Color3f(*out) if len(out) == 3 else out

    def query_unshared(self, position: Vec3, normal: Vec3 | None = None,
                       roughness: mi.Float | None = None, albedo: Vec3 | None = None,
                       direction: Vec3 | None = None,
                       albedo_spec: Vec3 | None = None) -> mi.Color3f | list[mi.Float]:
        """:meth:`query` with the surface features recomputed for this call.

        The naive pipeline the NIRC paper's Fig. 5 compares against; kept for
        the benchmark that measures what sharing saves.
        """
        surface = self.surface_features(position, normal, roughness, albedo, albedo_spec)
        return self.query(surface, direction)

    def predict_tensor(self, records: TrainingRecords) -> mi.TensorXf:
        """Tensor-mode inference with the inference weights: (n_outputs, N).

        Same numbers as :meth:`query_outputs` up to float summation order;
        used to compare CoopVec and tensor evaluation.
        """
        rows = self._input_rows(records, self._infer_position)
        y = self._infer_src(to_tensor(rows))
        if self.config.output.activation == "sigmoid":
            return sigmoid(y)
        return dr.maximum(y, 0.0)

    # ------------------------------------------------------------------
    # Parameters (for storage and tests)
    # ------------------------------------------------------------------
    def parameters(self) -> dict[str, np.ndarray]:
        """The latest (optimizer) parameters, flattened, as NumPy arrays."""
        return {k: np.asarray(_flat(v)) for k, v in self._params().items()}

    def inference_parameters(self) -> dict[str, np.ndarray]:
        """The parameters inference uses (EMA when enabled), as NumPy arrays."""
        return {k: np.asarray(_flat(v)) for k, v in self._inference_params().items()}

    def load_inference_parameters(self, params: dict[str, np.ndarray]) -> None:
        """Make ``params`` (as returned by :meth:`inference_parameters`) the weights.

        For stored, converged caches (the sweep's snapshots): afterwards
        :meth:`query` reproduces the cache they were saved from exactly.
        Training may continue from them, with fresh Adam moments and EMA.
        """
        current = self._params()
        if set(params) != set(current):
            raise ValueError(f"parameter names differ: expected {sorted(current)}, "
                             f"got {sorted(params)}")
        for key, value in current.items():
            flat = np.asarray(params[key], dtype=np.float32).ravel()
            if flat.size != dr.width(_flat(value)):
                raise ValueError(f"{key}: expected {dr.width(_flat(value))} values, "
                                 f"got {flat.size}")
            loaded = (type(value)(mi.Float(flat), value.shape) if dr.is_tensor_v(value)
                      else type(value)(flat))
            self._opt[key] = loaded
        if self._ema is not None:
            self._ema = {k: dr.zeros(type(v), v.shape) for k, v in self._params().items()}
        self._ema_steps = 0
        self._refresh_inference()

    # ------------------------------------------------------------------
    # Training
    # ------------------------------------------------------------------
    def train(self, records: TrainingRecords, steps: int | None = None,
              batch_size: int | None = None) -> list[float]:
        """Take ``steps`` Adam steps (default ``config.steps_per_frame``) on ``records``.

        Invalid records and records with non-finite targets or inputs are
        dropped and counted. Batches of ``batch_size`` (default
        ``config.batch_size``, at most the number of usable records) are
        consecutive slices of seeded random permutations of the usable
        records, so one frame's records are each used once before any repeats
        (as NRC does); a frame with fewer records than a batch repeats them.
        A step whose loss or gradients are not finite is skipped and counted.
        With ``config.converged_training`` set, a call after a converged loss
        takes at most its ``steps`` steps (:meth:`loss_converged`).
        Afterwards the inference network is refreshed. Returns the losses of
        the steps taken.
        """
        steps = self.config.steps_per_frame if steps is None else int(steps)
        rule = self.config.converged_training
        if rule is not None and steps > rule.steps and self.loss_converged():
            steps = rule.steps
            self.stats["reduced_frames"] += 1
        batch_size = self.config.batch_size if batch_size is None else int(batch_size)
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self._check_records(records)

        usable = self._usable_indices(records)
        n = dr.width(usable)
        losses: list[float] = []
        if n == 0 or steps <= 0:
            return losses
        # Records sharing a shading point (L_V's groups) are drawn whole.
        group = self.config.loss.records_per_point
        batch_size = max(batch_size // group, 1) * group
        # Always the configured batch size, repeating records when a frame has
        # fewer: the tensor-mode kernels bake the batch size into their IR, and
        # a new size per frame meant a JIT compilation (~1 s) per training step.
        draws = self._batch_indices(n, batch_size, steps, group)
        taken = []
        for s in range(steps):
            index = dr.gather(mi.UInt32, usable, mi.UInt32(draws[s]))
            self._attempted_steps += 1
            _detach_weights(self._opt)
            taken.append(self._step_fn(self._opt, self._ema or {}, self._counters, records,
                                       index))
            self._last_step = (records, index)
        # One read-back per frame: the losses are a result (the loss curve).
        dr.eval(taken)
        for loss, good in taken:
            if bool(good[0]):
                losses.append(float(loss[0]))
                self.stats["steps"] += 1
                self.stats["records_trained"] += batch_size
                if self._ema is not None:
                    self._ema_steps += 1
            else:
                self.stats["skipped_steps"] += 1
        self.loss_history += losses
        if rule is not None and losses:
            mean = sum(losses) / len(losses)
            ema = self.frame_loss_ema
            ema.append(mean if not ema else rule.ema_decay * ema[-1] + (1 - rule.ema_decay) * mean)
        self._refresh_inference()
        return losses

    def loss_converged(self) -> bool:
        """Whether the converged-training rule (``config.converged_training``)
        holds now: the moving average of the per-frame loss changed by less
        than ``tolerance`` (relative) over the last ``window`` training frames.
        Always False when the rule is off."""
        rule = self.config.converged_training
        ema = self.frame_loss_ema
        if rule is None or len(ema) <= rule.window:
            return False
        before, now = ema[-1 - rule.window], ema[-1]
        return abs(now - before) < rule.tolerance * abs(before)

    def evaluate_loss(self, records: TrainingRecords) -> float:
        """The configured loss of the inference network on ``records`` (no update)."""
        self._check_records(records)
        usable = self._usable_indices(records, count=False)
        recs = records.gather(usable)
        rows = self._input_rows(recs, self._infer_position)
        y = self._infer_src(to_tensor(rows))
        if self.config.output.activation == "sigmoid":
            y = sigmoid(y)
        loss = cache_loss(self.config.loss, y, to_tensor(recs.target_rows()))
        return float(loss.array[0])

    # ---- internals ----
    def _params(self) -> dict[str, Any]:
        return {k: dr.detach(self._opt[k]) for k in self._keys}

    def _inference_params(self) -> dict[str, Any]:
        if self._ema is None or self._ema_steps == 0:
            return self._params()
        # Debias like Adam's moments: the accumulator starts at 0.
        decay = self.config.ema_decay
        # Opaque so that a changing factor does not recompile the kernel.
        factor = dr.opaque(mi.Float, 1.0 / (1.0 - decay**self._ema_steps))
        return {k: _scaled(v, factor) for k, v in self._ema.items()}

    def _refresh_inference(self) -> None:
        """Pack the inference weights and point the inference grid at its table."""
        params = self._inference_params()
        for key in self._mlp_keys:
            self._infer_src[key] = params[key]
        dr.eval(self._infer_src)
        self._infer = PackedMLP(self._infer_src, self.config.n_surface_features,
                                self.split_first_layer)
        grid_data = params[GRID_KEY]
        dr.eval(grid_data)
        self._infer_position: PositionEncoding | ScreenLatentEncoding = (
            self.encoder.position.with_data(grid_data))

    def _input_rows(self, records: TrainingRecords,
                    position: PositionEncoding | ScreenLatentEncoding) -> list[mi.Float]:
        surface = self.encoder.surface(records.position, records.normal, records.roughness,
                                       records.albedo, records.albedo_spec,
                                       position_encoding=position)
        return [*surface, *self.encoder.direction(records.direction)]

    def _check_records(self, records: TrainingRecords) -> None:
        records.check_widths()
        n_targets = len(records.target_rows())
        if n_targets != self.n_outputs:
            raise ValueError(f"training targets have {n_targets} channels but the cache has "
                             f"{self.n_outputs} outputs")

    def _usable_indices(self, records: TrainingRecords, count: bool = True) -> mi.UInt32:
        """Indices of records that are valid with finite inputs and targets; where
        records come in groups sharing a shading point (L_V), of whole groups only."""
        n = len(records)
        valid = mi.Bool(True) if records.valid is None else mi.Bool(records.valid)
        valid = valid & dr.full(mi.Bool, True, n)
        finite_target = records.finite_targets()
        finite_input = records.finite_inputs()
        keep = valid & finite_target & finite_input
        group = self.config.loss.records_per_point
        if group > 1:
            if n % group:
                raise ValueError(f"the loss takes records in groups of {group} sharing a "
                                 f"shading point; got {n} records")
            whole = dr.block_sum(mi.UInt32(dr.select(keep, 1, 0)), group) == group
            keep &= dr.gather(mi.Bool, whole, dr.arange(mi.UInt32, n) // group)
        if count:
            invalid, bad_target, bad_input, kept = _tally(
                [~valid, valid & ~finite_target, valid & finite_target & ~finite_input, keep],
                keep)
            self.stats["dropped_invalid"] += invalid
            self.stats["dropped_nonfinite_targets"] += bad_target
            self.stats["dropped_nonfinite_inputs"] += bad_input
            self.stats["records_seen"] += kept
        return dr.compress(keep)

    def _batch_indices(self, n: int, batch: int, steps: int,
                       group: int = 1) -> list[np.ndarray]:
        """``steps`` batches of indices into ``n`` records, from the seed and step count;
        with ``group`` > 1, permutations of whole groups of consecutive records."""
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, self._attempted_steps]))
        needed = steps * batch // group
        groups = n // group
        perms = [rng.permutation(groups) for _ in range(-(-needed // groups))]
        first = np.concatenate(perms)[:needed].astype(np.uint32) * group
        flat = (first[:, None] + np.arange(group, dtype=np.uint32)).ravel()
        return [flat[s * batch:(s + 1) * batch] for s in range(steps)]

    def _train_step(self, opt: Adam, ema: dict[str, Any], counters: dict[str, Any],
                    records: TrainingRecords, index: mi.UInt32) -> tuple[mi.Float, mi.Bool]:
        """One Adam step on the records at ``index``: (its loss, whether it was taken).

        A function of its arguments only (the optimizer's weights and moments, the EMA
        of the weights, the step counter, the records), updating them in place, so that
        a frozen replay (renderers.frozen) does what the traced step does. A step whose
        loss or gradients are not finite leaves everything unchanged (Adam's masked
        update), decided on the device: no read-back inside the step.
        """
        batch = records.gather(index)

        # ---- Bind the optimizer's parameters (Adam owns them) ----
        for key in self._keys:   # handed over detached (_detach_weights)
            dr.enable_grad(opt[key])
        for key in self._mlp_keys:
            self._net[key] = opt[key]
        position = self.encoder.position.with_data(opt[GRID_KEY])

        # ---- Forward (tensor mode) and loss (Eq. 18 or L2) ----
        gradients = LayerGradients()
        y = mlp_forward_tensor(self._net, self._input_rows(batch, position), gradients)
        if self.config.output.activation == "sigmoid":
            y = sigmoid(y)
        # clamped_linear stays linear here: a clamp would stop the gradient of
        # negative predictions, which then could never recover.
        loss = cache_loss(self.config.loss, y, to_tensor(batch.target_rows()))
        dr.backward(loss)

        # ---- Taken only if everything is finite ----
        good = dr.isfinite(loss.array) & gradients.finite()
        lookup = position.lookup
        if lookup is not None and lookup.finite is not None:
            # The fixed-point table gradient is NaN everywhere or finite
            # everywhere (grid_grad.py) and its lookup says which: no
            # reduction over the whole table (~1.3M entries) per step, and
            # the gradient stays lazy, computed inside Adam's kernel.
            good &= lookup.finite
        else:
            good &= dr.count(~dr.isfinite(_flat(dr.grad(opt[GRID_KEY])))) == 0

        # ---- Adam step (+ EMA of the weights), masked by ``good`` ----
        opt.set_learning_rate(self.config.optimizer.learning_rate_at(counters["steps"]))
        opt.step(active=good, eval=False)
        if ema:
            decay = self.config.ema_decay
            for key in self._keys:
                acc = dr.fma(ema[key], decay, dr.detach(opt[key]) * (1.0 - decay))
                ema[key] = _where(good, acc, ema[key])
        counters["steps"] = counters["steps"] + dr.select(good, 1, 0)
        return loss.array, good


def _detach_weights(opt: Adam) -> None:
    """Hold ``opt``'s weights without their gradients (the training step enables them):
    on every call of a frozen function, Dr.Jit walks a gradient-enabled input's gradient
    and clears it with a kernel of its own (a 2.4 MB fill for the hash grid's), and its
    walk of the step's inputs cost twice as long (0.19 against 0.11 ms)."""
    for key, (value, *rest) in opt.state.items():
        opt.state[key] = (dr.detach(value), *rest)


def _tally(masks: Sequence[mi.Bool], *evaluated: Any) -> list[int]:
    """How many lanes of each of ``masks`` (disjoint) are set, counted in one kernel
    (integer atomics: exact) that also evaluates ``evaluated``, and read back at once: a
    ``dr.count`` per mask was a kernel, a reduction and a read-back each."""
    slot = mi.UInt32(len(masks))
    for at, mask in reversed(list(enumerate(masks))):
        slot = dr.select(mask, at, slot)
    counts = dr.zeros(mi.UInt32, len(masks))
    dr.scatter_add(counts, 1, slot, slot < len(masks))
    dr.eval(counts, *evaluated)
    return [int(c) for c in counts.numpy()]


def _flat(value: Any) -> mi.Float:
    """The flat Float storage of a Float or a tensor."""
    return value.array if dr.is_tensor_v(value) else value


def _fresh(tree: Any) -> Any:
    """``tree`` with new containers and new array objects for the same values (and their
    AD edges): a frozen replay updates the array objects it was given in place, so a
    step on a copy made otherwise would change the original."""
    if dr.is_array_v(tree):
        return type(tree)(tree)
    if isinstance(tree, tuple | list):
        return type(tree)(_fresh(item) for item in tree)
    if isinstance(tree, dict):
        return {key: _fresh(value) for key, value in tree.items()}
    return tree


def _where(mask: mi.Bool, new: Any, old: Any) -> Any:
    """``new`` where the width-1 ``mask`` is set, else ``old`` (Floats or tensors)."""
    if dr.is_tensor_v(old):
        return type(old)(dr.select(mask, _flat(new), _flat(old)), old.shape)
    return dr.select(mask, new, old)
