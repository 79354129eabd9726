"""A conditional normalizing flow on the sphere: piecewise-quadratic coupling layers
[Müller et al. 2019, "Neural Importance Sampling" (NIS), Sec. 3], the shape of the
neural control variates [Müller et al. 2020, "Neural Control Variates" (NCV)] as the
NIRC paper configured them (Sec. 6.1: 64 bins, 2 repetitions, 6-layer MLPs of 64
neurons, cylindrical directions, one flow per colour channel, one-blob latents with
32 bins).

**Directions.** A unit direction w = (sin t cos p, sin t sin p, cos t) is mapped to
the unit square by the cylindrical (Lambert equal-area) coordinates

    u_1 = (cos t + 1) / 2,      u_2 = p / (2 pi) + 1/2,      dw = 4 pi du_1 du_2,

so a density q_u on the square is the density q(w) = q_u(u) / (4 pi) on the sphere
(Archimedes: d(cos t) dp = 2 du_1 * 2 pi du_2).

**Coupling layers** (NIS Sec. 3.1-3.3). Each layer maps one coordinate u_A through a
piecewise-quadratic CDF whose K bins are predicted by an MLP m from the other
coordinate u_B (one-blob encoded, NIS Sec. 4.2) and the conditioning features c;
u_B passes unchanged:

    z_A = C(u_A; m(oneblob(u_B), c)),   z_B = u_B,   |det dz/du| = C'(u_A).

With raw outputs (W^_1..K, V^_1..K+1) the bin widths and vertex heights are (NIS Eq. 8)

    W_b = exp(W^_b) / sum_k exp(W^_k),
    V_b = exp(V^_b) / sum_k (exp(V^_k) + exp(V^_{k+1})) / 2 * W_k,

so the density C' = lerp(V_b, V_{b+1}, a) in bin b (a the position inside the bin) is
continuous, positive and integrates to 1; its integral (NIS Eq. 9)

    C(x) = sum_{k<b} (V_k + V_{k+1}) / 2 * W_k + a W_b V_b + a^2 W_b (V_{b+1} - V_b) / 2

is inverted by solving that quadratic for a.

**A floor under the bins.** Each transform is mixed with the identity (the uniform
density) in the share delta (``uniform_mix``):

    W_b <- (1 - delta) W_b + delta / K,      V_b <- (1 - delta) V_b + delta,

which keeps sum_b W_b = 1 and the integral sum_b (V_b + V_{b+1}) / 2 W_b = 1 (the
learned part integrates to 1 over the mixed widths), so the density stays normalised
while C' >= delta and every bin is at least delta / K wide. Without it, training
collapses bins (on sky 16x16 the smallest width fell to 1e-6 and the smallest density
to 4e-6 within 30 steps): once exp() underflows, a width of 0 gives 0/0 in the bin's
position and a density of 0 gives log 0 = -inf, whose gradient (q d log q = 0 * inf) is
NaN while the loss stays finite, and Adam writes NaN into every weight.

``repetitions`` R gives 2R layers, the
coordinate transformed alternating. The flow maps data u to a latent z uniform on the
square (:meth:`SphereFlow.forward`, the density direction), so log q_u(u) is the sum
of the layers' log C'; :meth:`SphereFlow.inverse` maps z back (sampling).

Each colour channel has a flow of its own (2R MLPs each). The MLPs run in tensor mode
(renderers.caches.cache.mlp_forward_tensor) in training and evaluation alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi
from drjit import nn
from pydantic import BaseModel, ConfigDict, Field

from renderers.caches.cache import mlp_forward_tensor
from renderers.caches.encodings import one_blob, unit_vector
from renderers.seeding import derive_seed

#: dw = CYLINDER_JACOBIAN du_1 du_2 (module docstring).
CYLINDER_JACOBIAN = 4.0 * math.pi

#: Feature rows, one Float each (renderers.caches.encodings).
Rows = list[Any]


class FlowConfig(BaseModel):
    """The flow of one colour channel and how many channels (module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    bins: int = Field(64, ge=2, le=256, description="bins K of each coupling transform")
    repetitions: int = Field(2, ge=1, le=8,
                             description="pairs of coupling layers (each coordinate once)")
    blob_bins: int = Field(32, ge=1, le=128,
                           description="one-blob bins of the pass-through coordinate")
    width: int = Field(64, ge=1, le=1024, description="MLP neurons per hidden layer")
    hidden_layers: int = Field(4, ge=1, le=16,
                               description="hidden layers (4: the 6-layer MLP of NIRC)")
    channels: int = Field(3, ge=1, le=3, description="independent flows, one per channel")
    uniform_mix: float = Field(1e-3, ge=0.0, lt=1.0,
                               description="share delta of the uniform density mixed into "
                                           "each transform: C' >= delta, widths >= delta / K")

    @property
    def couplings(self) -> int:
        return 2 * self.repetitions

    @property
    def raw_outputs(self) -> int:
        """K widths and K + 1 heights per coupling MLP."""
        return 2 * self.bins + 1


def to_cylindrical(w: Any) -> tuple[mi.Float, mi.Float]:
    """(u_1, u_2) in [0, 1]^2 of a direction (module docstring)."""
    w = unit_vector(w)
    u1 = dr.clip(dr.fma(w.z, 0.5, 0.5), 0.0, 1.0)
    u2 = dr.clip(dr.fma(dr.atan2(w.y, w.x), 0.5 / dr.pi, 0.5), 0.0, 1.0)
    return u1, u2


def from_cylindrical(u1: mi.Float, u2: mi.Float) -> mi.Vector3f:
    """The unit direction of (u_1, u_2); inverse of :func:`to_cylindrical`."""
    cos_t = dr.fma(u1, 2.0, -1.0)
    sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
    sin_p, cos_p = dr.sincos(dr.fma(u2, dr.two_pi, -dr.pi))
    return mi.Vector3f(sin_t * cos_p, sin_t * sin_p, cos_t)


@dataclass
class BinTable:
    """The K bins of every lane's transform, lane-major (lane n's bin b at n K + b):
    widths W_b, the heights V_b and V_{b+1} at the bin's vertices, its left edge and the
    CDF there. Arrays of K N values cost a few Dr.Jit operations per layer, where one
    array per bin cost thousands (the Python side dominated small renders)."""

    bins: int
    widths: mi.Float
    left_heights: mi.Float
    right_heights: mi.Float
    lefts: mi.Float
    belows: mi.Float

    def locate(self, value: mi.Float, edges: mi.Float) -> mi.UInt32:
        """Per lane, the last bin whose edge (``lefts`` or ``belows``) ``value`` reaches."""
        reached = dr.block_sum(dr.select(dr.repeat(value, self.bins) >= edges, 1.0, 0.0),
                               self.bins)
        return mi.UInt32(dr.clip(reached - 1.0, 0.0, self.bins - 1.0))

    def pick(self, values: mi.Float, index: mi.UInt32) -> mi.Float:
        """Each lane's entry ``index`` of a per-bin array."""
        lanes = dr.width(values) // self.bins
        return dr.gather(mi.Float, values, dr.arange(mi.UInt32, lanes) * self.bins + index)


def bin_widths(raw: mi.Float, bins: int, mix: float) -> mi.Float:
    """W_b = exp(W^_b) / sum_k exp(W^_k) per lane (NIS Eq. 8), mixed with the uniform
    widths in the share ``mix`` (module docstring); the lane's maximum is subtracted for
    range only."""
    top = dr.repeat(dr.block_reduce(dr.ReduceOp.Max, dr.detach(raw), bins), bins)
    exp_widths = dr.exp(raw - top)
    return with_uniform(exp_widths / dr.repeat(dr.block_sum(exp_widths, bins), bins), mix,
                        1.0 / bins)


def with_uniform(value: mi.Float, mix: float, uniform: float) -> mi.Float:
    """(1 - mix) value + mix uniform: a bin's width or height mixed with the uniform
    transform's (``uniform``: 1/K or 1; module docstring)."""
    return dr.fma(value, 1.0 - mix, mix * uniform)


def bin_table(raw: mi.TensorXf, bins: int, mix: float) -> BinTable:
    """The bins from an MLP's raw outputs (rows W^_1..K, V^_1..K+1; NIS Eq. 8):
    V_b = exp(V^_b) / sum_k (exp(V^_k) + exp(V^_{k+1})) / 2 W_k, so the density is
    continuous and integrates to 1; widths and heights mixed with the uniform transform
    in the share ``mix`` (module docstring)."""
    lanes = raw.shape[1]
    slot = dr.arange(mi.UInt32, bins * lanes)
    lane, b = slot // bins, slot % bins

    def rows(first: int) -> mi.Float:   # row first + b of each lane, lane-major
        return dr.gather(mi.Float, raw.array, dr.fma(b + first, lane_count(lanes), lane))

    widths = bin_widths(rows(0), bins, mix)
    raw_left, raw_right = rows(bins), rows(bins + 1)
    top = dr.repeat(dr.block_reduce(dr.ReduceOp.Max, dr.detach(dr.maximum(raw_left, raw_right)),
                                    bins), bins)
    exp_left, exp_right = dr.exp(raw_left - top), dr.exp(raw_right - top)
    area = dr.repeat(dr.block_sum(0.5 * (exp_left + exp_right) * widths, bins), bins)
    left, right = with_uniform(exp_left / area, mix, 1.0), with_uniform(exp_right / area, mix, 1.0)
    table = BinTable(bins, widths, left, right,
                     lefts=dr.block_prefix_sum(widths, bins, exclusive=True),
                     belows=dr.block_prefix_sum(0.5 * (left + right) * widths, bins,
                                                exclusive=True))
    dr.eval(table.widths, table.left_heights, table.right_heights, table.lefts, table.belows)
    return table


def bin_density(fraction: mi.Float, left: mi.Float, right: mi.Float) -> mi.Float:
    """C' inside a bin: the heights at its vertices interpolated linearly."""
    return dr.fma(fraction, right - left, left)


def bin_fraction(mass: mi.Float, width: mi.Float, left: mi.Float,
                 right: mi.Float) -> mi.Float:
    """The position a in [0, 1] inside a bin whose CDF rose by ``mass`` from its left
    edge: the root of W (V_r - V_l) / 2 a^2 + W V_l a - mass = 0, in the form without
    cancellation, 2 mass / (W V_l + sqrt((W V_l)^2 + 2 W (V_r - V_l) mass))."""
    linear = width * left
    discriminant = dr.maximum(linear * linear + 2.0 * width * (right - left) * mass, 0.0)
    return dr.clip(2.0 * mass / dr.maximum(linear + dr.sqrt(discriminant), 1e-30), 0.0, 1.0)


def quadratic_cdf(x: mi.Float, table: BinTable) -> tuple[mi.Float, mi.Float]:
    """(C(x), C'(x)) of the piecewise-quadratic transform (module docstring)."""
    b = table.locate(x, table.lefts)
    width = table.pick(table.widths, b)
    left, right = table.pick(table.left_heights, b), table.pick(table.right_heights, b)
    fraction = dr.clip((x - table.pick(table.lefts, b)) / width, 0.0, 1.0)
    y = table.pick(table.belows, b) + width * fraction * dr.fma(0.5 * fraction, right - left,
                                                                left)
    return y, bin_density(fraction, left, right)


def quadratic_inverse(y: mi.Float, table: BinTable) -> tuple[mi.Float, mi.Float]:
    """(C^-1(y), C'(C^-1(y))): the bin whose CDF range holds y, then :func:`bin_fraction`."""
    b = table.locate(y, table.belows)
    width = table.pick(table.widths, b)
    left, right = table.pick(table.left_heights, b), table.pick(table.right_heights, b)
    fraction = bin_fraction(y - table.pick(table.belows, b), width, left, right)
    return dr.clip(dr.fma(fraction, width, table.pick(table.lefts, b)), 0.0, 1.0), \
        bin_density(fraction, left, right)


def coupling_mlp(config: FlowConfig) -> nn.Sequential:
    """One coupling layer's (unallocated) MLP: ReLU hidden layers, linear raw outputs."""
    layers: list[nn.Module] = []
    for _ in range(config.hidden_layers):
        layers += [nn.Linear(-1, config.width), nn.ReLU()]
    layers.append(nn.Linear(-1, config.raw_outputs))
    return nn.Sequential(*layers)


def network_tensor(net: nn.Sequential, rows: Rows) -> mi.TensorXf:
    """A tensor-mode MLP applied to feature rows: outputs of shape (outputs, N)."""
    # Rows evaluated first: the MLP's input copy (to_tensor) takes the width as a
    # constant, so only that small copy compiles per width; an unevaluated input also
    # made every matmul's kernel compile anew.
    dr.eval(rows)
    return mlp_forward_tensor(net, rows)


def network_rows(net: nn.Sequential, rows: Rows) -> Rows:
    """:func:`network_tensor`'s outputs as rows."""
    out = network_tensor(net, rows)
    lanes = out.shape[1]
    lane = dr.arange(mi.UInt32, lanes)
    return [dr.gather(mi.Float, out.array, lane + lane_count(i * lanes))
            for i in range(out.shape[0])]


def lane_count(value: int) -> mi.UInt32:
    """An offset or count as an opaque array, not a literal of the kernel: the kernels
    then serve every batch and wavefront width instead of compiling anew for each."""
    return dr.opaque(mi.UInt32, value)


class SphereFlow:
    """One conditional flow per colour channel on the unit square / sphere (module
    docstring), conditioned on ``n_condition`` feature rows, initialised from ``seed``."""

    def __init__(self, config: FlowConfig, n_condition: int, seed: int = 0) -> None:
        self.config = config
        self.n_condition = n_condition
        n_inputs = config.blob_bins + n_condition
        self.networks = [[coupling_mlp(config).alloc(
            mi.TensorXf, n_inputs, rng=dr.rng(derive_seed(seed, "flow", channel, layer)))
            for layer in range(config.couplings)] for channel in range(config.channels)]

    def parameters(self) -> dict[str, Any]:
        """Every weight and bias, keyed 'flow.<channel>.<layer>.<name>' (the optimizer's
        keys; :meth:`bind` takes them back)."""
        return {f"flow.{c}.{k}.{key}": value
                for c, nets in enumerate(self.networks) for k, net in enumerate(nets)
                for key, value in net.items()}

    def bind(self, parameters: dict[str, Any]) -> None:
        for c, nets in enumerate(self.networks):
            for k, net in enumerate(nets):
                for key in list(net.keys()):
                    net[key] = parameters[f"flow.{c}.{k}.{key}"]

    def _table(self, channel: int, layer: int, passed: mi.Float, condition: Rows) -> BinTable:
        rows = one_blob(passed, self.config.blob_bins) + list(condition)
        return bin_table(network_tensor(self.networks[channel][layer], rows), self.config.bins,
                         self.config.uniform_mix)

    def _check(self, condition: Rows) -> None:
        if len(condition) != self.n_condition:
            raise ValueError(f"the flow is conditioned on {self.n_condition} features, "
                             f"got {len(condition)}")

    # Every layer's bins and transform are evaluated on their own: the layers then reuse
    # the same few kernels, where one kernel of the whole flow compiled for seconds anew
    # whenever the set of arrays it kept changed.
    def forward(self, u: tuple[mi.Float, mi.Float], condition: Rows,
                channel: int) -> tuple[tuple[mi.Float, mi.Float], mi.Float]:
        """(z, log |det dz/du|): data on the square to the uniform latent."""
        self._check(condition)
        z, log_det = [mi.Float(u[0]), mi.Float(u[1])], mi.Float(0.0)
        for layer in range(self.config.couplings):
            a = layer % 2
            z[a], density = quadratic_cdf(z[a], self._table(channel, layer, z[1 - a],
                                                            condition))
            log_det += dr.log(density)
            dr.eval(z[a], log_det)
        return (z[0], z[1]), log_det

    def inverse(self, z: tuple[mi.Float, mi.Float], condition: Rows,
                channel: int) -> tuple[tuple[mi.Float, mi.Float], mi.Float]:
        """(u, log |det du/dz|): the uniform latent back to the square (sampling)."""
        self._check(condition)
        u, log_det = [mi.Float(z[0]), mi.Float(z[1])], mi.Float(0.0)
        for layer in reversed(range(self.config.couplings)):
            a = layer % 2
            u[a], density = quadratic_inverse(u[a], self._table(channel, layer, u[1 - a],
                                                                condition))
            log_det -= dr.log(density)
            dr.eval(u[a], log_det)
        return (u[0], u[1]), log_det

    def sphere_density(self, w: Any, condition: Rows) -> Rows:
        """q_c(w) = q_u(u(w)) / (4 pi) for each channel c, w a unit direction."""
        u = to_cylindrical(w)
        return [dr.exp(self.forward(u, condition, c)[1]) * (1.0 / CYLINDER_JACOBIAN)
                for c in range(self.config.channels)]
