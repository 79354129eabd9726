"""The inference network: packed weights evaluated on cooperative vectors.

``nn.pack(..., layout='inference')`` turns the trained tensor-mode weights
into the layout ``nn.matvec`` evaluates fastest; evaluation runs on evaluated
arrays and inside symbolic ``@dr.syntax`` loops alike.

The first layer is split by input group. Its pre-activation is

    h_1 = W_s s + b_1 + W_d e(w),

where s are the per-surface features and e(w) the direction encoding. The
term z = W_s s + b_1 does not depend on the direction, so it is computed once
per shading point together with s and shared by the N_c directions — NIRC
paper Sec. 4.5 extends sharing "to other shared input parameters and their
corresponding encoding outputs"; this carries it one matrix further. Per
direction only W_d e(w) and the remaining layers are evaluated. On the 2-core
CPU this made a cache sample in an N_c loop 1.5-1.7x cheaper than
concatenating s and e(w) (see benchmarks/bench_cache.py); results equal the
unsplit network up to float summation order.

Precision: Dr.Jit's cooperative vectors evaluate float32 matrices on the LLVM
backend only; on CUDA (OptiX) both the packed matrices and the vectors must be
float16. :func:`half_precision` therefore chooses float16 on CUDA and float32
elsewhere; a half-precision network converts its inputs to float16 and its
outputs back to float32, so callers always see float32 arrays. Half precision
is what the NRC and NIRC papers' own implementations (tiny-cuda-nn) infer with;
on the CPU the float32 images stay what they were.
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi
from drjit import nn


def half_precision(backend: dr.JitBackend | None = None) -> bool:
    """True where cooperative vectors need float16 (CUDA), False where float32 works."""
    backend = dr.backend_v(mi.Float) if backend is None else backend
    return backend == dr.JitBackend.CUDA


class PackedMLP:
    """Inference form of an allocated tensor-mode ``nn.Sequential`` MLP.

    Args:
        net: the MLP (``nn.Linear`` layers with bias, activation modules).
        n_surface: number of leading inputs that are per-surface features;
            the rest are direction features.
        split_first_layer: True for the split evaluation described in the
            module docstring; False packs the whole network and evaluates the
            concatenated input (for comparison).
        half: pack and evaluate in float16 (default: :func:`half_precision`).
    """

    def __init__(self, net: nn.Sequential, n_surface: int, split_first_layer: bool = True,
                 half: bool | None = None):
        self.split = split_first_layer
        self.n_surface = n_surface
        self.half = half_precision() if half is None else half
        self._value_type: type = dr.float16_array_t(mi.Float) if self.half else mi.Float
        if not split_first_layer:
            self.full = nn.pack(_cast_weights(net, self.half), layout="inference")
            dr.eval(self.full)
            return
        first, *rest = net.layers
        if not isinstance(first, nn.Linear) or first.bias is None:
            raise TypeError("the MLP must start with a biased nn.Linear layer")
        w1 = first.weights
        n_in = w1.shape[1]
        self.n_direction = n_in - n_surface
        tensors: list[Any] = [w1[:, :n_surface], first.bias]
        if self.n_direction > 0:
            tensors.append(w1[:, n_surface:])
        plan: list[Any] = []  # remaining layers: ('linear', i) or an activation module
        for layer in rest:
            if isinstance(layer, nn.Linear):
                plan.append(("linear", len(tensors)))
                tensors += [layer.weights, layer.bias]
            else:
                plan.append(layer)
        self.views = nn.pack(*(_cast_weights(t, self.half) for t in tensors),
                             layout="inference")
        dr.eval(self.views)
        self.plan = plan

    def arrays(self) -> Any:
        """What evaluation reads of the weights (a frozen frame's argument): split, the
        one buffer that ``nn.pack`` packed every matrix into (the views' offsets and
        shapes are the architecture's, the same for any weights); else the packed
        network. Handed the views instead, Dr.Jit walked their fields on every call:
        a frozen call taking `nrc-di`'s views cost 0.12 ms more than one taking a
        Float."""
        return self.views[0].buffer if self.split else self.full

    def bind(self, arrays: Any) -> None:
        """Evaluate with ``arrays`` (from :meth:`arrays`; a frozen frame's argument)."""
        if self.split:
            self.views = tuple(_reading(view, arrays) for view in self.views)
        else:
            self.full = arrays

    def surface(self, rows: list[mi.Float]) -> list[mi.Float]:
        """Per-surface part: W_s s + b_1 (or the rows themselves if not split)."""
        if not self.split:
            return list(rows)
        return self._out(nn.matvec(self.views[0], self._in(rows), self.views[1]))

    def finish(self, surface: list[mi.Float], direction_rows: list[mi.Float]) -> list[mi.Float]:
        """Network outputs (pre output-activation) for one direction."""
        if not self.split:
            return self._out(self.full(self._in([*surface, *direction_rows])))
        h = self._in(surface)
        if self.n_direction > 0:
            h = h + nn.matvec(self.views[2], self._in(direction_rows))
        for step in self.plan:
            if isinstance(step, tuple):
                i = step[1]
                h = nn.matvec(self.views[i], h, self.views[i + 1])
            else:
                h = step(h)
        return self._out(h)

    def _in(self, rows: list[mi.Float]) -> nn.CoopVec:
        """A cooperative vector of ``rows`` in the network's precision."""
        return nn.CoopVec(*(self._value_type(r) for r in rows))

    @staticmethod
    def _out(h: nn.CoopVec) -> list[mi.Float]:
        """The rows of ``h`` as float32 arrays."""
        return [mi.Float(r) for r in h]


def _reading(view: nn.MatrixView, buffer: Any) -> nn.MatrixView:
    """``view`` (its layout, offset, shape, ...) into ``buffer``."""
    other = nn.MatrixView()
    for name in nn.MatrixView.DRJIT_STRUCT:
        setattr(other, name, buffer if name == "buffer" else getattr(view, name))
    return other


def _cast_weights(weights: Any, half: bool) -> Any:
    """``weights`` (a tensor or a network) in float16 where ``half``, else as is."""
    if not half:
        return weights
    if isinstance(weights, nn.Sequential):
        return nn.Sequential(*(_cast_layer(layer) for layer in weights.layers))
    return dr.float16_array_t(type(weights))(weights)


def _cast_layer(layer: nn.Module) -> nn.Module:
    """A linear layer with float16 weights and bias; any other layer as is."""
    if not isinstance(layer, nn.Linear):
        return layer
    half = nn.Linear(*layer.config)
    half.weights = _cast_weights(layer.weights, True)
    half.bias = None if layer.bias is None else _cast_weights(layer.bias, True)
    return half
