"""A hashed-grid radiance cache whose records track three moments (the
variance-trading paper [VTT24], Sec. 4.4 and 5; docs/variance_trading.md).

A record stands for a partition P of surface points y (a grid cell, optionally one of
six normal bins). For the one-segment estimate Y at a point y of the partition (the
next segment's light plus the cache at its end, sampled as the path tracer samples
it) the record keeps running averages of

* E[Y] (RGB): the cache's radiance rc;
* E[Y^2] (luminance): the second moment;
* E[E[Y | y]^2] (luminance): the *marginal* second moment, estimated per point with a
  U-statistic over its K independent samples, ((sum Y)^2 - sum Y^2) / (K (K - 1)): every
  ordered pair of distinct samples, whose product is an unbiased estimate of
  E[Y | y]^2 (a sample paired with itself would add Var[Y | y] / K).

from which (paper, Sec. 4.4 and appendix A)

* the average local variance E[V[Y | y]] = E[Y^2] - E[E[Y | y]^2], which variance
  bounding uses instead of the plain variance (that one also holds the spread of
  E[Y | y] across the cell), and
* the average squared bias E[(E[Y | y] - E[Y])^2] = E[E[Y | y]^2] - E[Y]^2 of using the
  cell's value at any of its points, the MSE rule's local bias. It is formed within each
  pass, from that pass's samples alone, and only then averaged over passes: E[Y]^2 by the
  products M_v M_w of the sample means of two *distinct* vertices of the record
  (independent, so E[M_v M_w] = E[Y]^2), and E[E[Y | y]^2] by the U-statistic above.
  Averaging E[E[Y|y]^2] and E[Y] over passes first would add the variance of the
  record's mean over time (its drift while radiance propagates, and the noise of the
  records it reads) to the bias. A pass that updates a record from one vertex gives no
  such estimate.

Unknown bias: a record that no pass has updated from two vertices (one representative
so far: 7 % of cornell-box's records and 15 % of door's after the pre-fill, 32x32) has
no squared-bias estimate. Its stored 0 would read as unbiased, and the MSE rule would
end every path there; a lookup says so instead (``bias_known``), and the rule treats
such a record as it treats a missing one: a path does not end in it, and an update
sample whose hit reads it adds 0 to the deferred squared bias, as one reading no
record does (the path would go on there, not end).

and, for the MSE rule's look-ahead (Sec. 4.3), the *deferred* squared bias
E[(f cos / p)^2 b^2(x)] of ending one vertex later: each sample's squared BSDF weight
(luminance) times the squared bias of the record its hit x reads (0 where it reads
none), averaged like E[Y]. It is a property of the record, so a path's decision to
stop at y depends on its prefix only, never on the sample that continues it.

History: a record's averages weigh a pass's observations n by n / min(count + n, H)
with H = ``max_history`` (or the shorter window a pre-fill passes): the plain mean
until H observations, then an exponential average over about the last H.
:meth:`MomentGrid.restart_history` keeps what the records hold as one observation, so
the long history starts from the pre-fill's equilibrium.

Keys: the integer cell of a position (and the normal's bin) hashed twice, once for the
slot and once as a checksum stored in the slot (0 = empty); linear probing over
``max_probes`` slots; an insertion that loses a race for an empty slot probes on. A key
that finds no slot is a miss, never another cell's record.

Reproducible with several threads: a pass's writes do not depend on the order in which
threads run. Its sums into the records are 64-bit fixed-point integer sums
(:func:`order_free_sum`; float atomics would add in a run-dependent order, and float
addition is not associative), keys racing for an empty slot are settled by an atomic
maximum (the largest checksum takes it), and lanes storing a representative in one
place by the largest lane index. One seed then gives the same records, and the same
image, bit for bit at any thread count.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi

from renderers.caches.grid_config import MomentGridConfig
from renderers.caches.grid_grad import fixed_point_add, fixed_point_gradient, fixed_point_scale

#: 2^32 / golden ratio, and the constants of MurmurHash3's 32-bit finalizer.
_GOLDEN = 0x9E3779B9
_PRIMES = (0x8DA6B343, 0xD8163841, 0xCB1AB31F, 0x165667B1)


def _finalize(h: mi.UInt32) -> mi.UInt32:
    h ^= h >> 16
    h *= 0x85EBCA6B
    h ^= h >> 13
    h *= 0xC2B2AE35
    return h ^ (h >> 16)


def normal_bin(normal: mi.Vector3f) -> mi.UInt32:
    """0..5: the normal's dominant axis (x, y, z) times two, plus one when negative."""
    a = dr.abs(normal)
    is_x = (a.x >= a.y) & (a.x >= a.z)
    is_y = ~is_x & (a.y >= a.z)
    axis = dr.select(is_x, 0, dr.select(is_y, 1, 2))
    component = dr.select(is_x, normal.x, dr.select(is_y, normal.y, normal.z))
    return mi.UInt32(axis * 2 + dr.select(component < 0, 1, 0))


def marginal_second_moment(sum_y: mi.Float, sum_y2: mi.Float, k: int) -> mi.Float:
    """The U-statistic of E[Y | y]^2 from K independent samples at one point: the mean
    product over the K (K - 1) ordered pairs of distinct samples,
    ((sum Y)^2 - sum Y^2) / (K (K - 1)), unbiased since E[Y_i Y_j] = E[Y | y]^2 for
    i != j ([Lee90]; [VTT24] Sec. 4.4)."""
    return (dr.square(sum_y) - sum_y2) / (k * (k - 1))


def order_free_sum(value: mi.Float, index: mi.UInt32, active: mi.Bool, size: int) -> mi.Float:
    """The sums of ``value`` over the ``active`` lanes at each ``index`` (``size``
    entries), the same bits whatever order threads add in: each term in 64-bit fixed
    point under a power-of-two scale at which no sum can overflow (grid_grad), whose
    quantum is about max |value| x lanes x 2^-62, far below float32's rounding of a sum.
    An entry with a non-finite term is NaN (a float sum would be NaN or infinite)."""
    finite = dr.isfinite(value)
    term = dr.select(active & finite, value, 0.0)
    scale, _finite = fixed_point_scale([term], 1)
    total = dr.zeros(dr.int64_array_t(mi.Float), size)
    fixed_point_add(total, term, index, scale, active & finite)
    non_finite = dr.zeros(mi.UInt32, size)
    dr.scatter_add(non_finite, 1, index, active & ~finite)
    return dr.select(non_finite == 0, fixed_point_gradient(total, scale, True), dr.nan)


def _weight(count: mi.Float, n: mi.Float, history: mi.Float | float) -> mi.Float:
    """The weight of a pass's n observations in a running average over ``count``
    (module doc, History); a pass with more observations than the history holds
    replaces the average."""
    return dr.minimum(n / dr.maximum(dr.minimum(count + n, history), 1.0), 1.0)


def _running(average: mi.Float, count: mi.Float, value: mi.Float, n: mi.Float,
             history: mi.Float | float) -> tuple[mi.Float, mi.Float]:
    """(average, count) after folding in ``value`` with ``n`` observations."""
    return (dr.lerp(average, value, _weight(count, n, history)),
            dr.minimum(count + n, history))


@dataclass
class GridValue:
    """What a lookup returns; zeros where ``found`` is False."""

    radiance: mi.Color3f
    local_variance: mi.Float
    squared_bias: mi.Float
    deferred_bias: mi.Float   # E[(f cos / p)^2 b^2] at the next vertex (module doc)
    found: mi.Bool
    # Whether the record holds a squared-bias estimate: a pass gives one only from two
    # of its vertices, so a record updated from one at a time has none and its
    # ``squared_bias`` (0) says nothing (module doc, Unknown bias).
    bias_known: mi.Bool


class MomentGrid:
    """The table and its records (see the module doc). ``keys`` holds each slot's
    checksum; per slot: ``count`` (vertex estimates averaged so far, capped at the
    history), ``mean`` (RGB, 3 per slot), ``second``, ``marginal``, ``deferred`` and the
    per-pass squared bias ``bias`` (luminance) with its own ``bias_count`` (passes give
    it only from two vertices on); ``vertices`` the representative points (position and
    normal, 6 floats each, ``vertices_per_record`` per slot) with ``vertex_used``."""

    #: The arrays a lookup reads (:meth:`lookup_arrays`, :meth:`bind_lookup`): what a frozen
    #: render that looks the grid up takes as its arguments (renderers.frozen).
    LOOKUP_ARRAYS = ("keys", "count", "mean", "second", "marginal", "bias", "bias_count",
                     "deferred")
    #: Every array of its state: the lookup's and the representatives (:meth:`arrays`).
    ARRAYS = (*LOOKUP_ARRAYS, "vertices", "vertex_used")

    def __init__(self, config: MomentGridConfig) -> None:
        self.config = config
        size = config.table_size
        self.keys = dr.zeros(mi.UInt32, size)
        self.count = dr.zeros(mi.Float, size)
        self.mean = dr.zeros(mi.Float, 3 * size)
        self.second = dr.zeros(mi.Float, size)
        self.marginal = dr.zeros(mi.Float, size)
        self.bias = dr.zeros(mi.Float, size)
        self.bias_count = dr.zeros(mi.Float, size)
        self.deferred = dr.zeros(mi.Float, size)
        self.vertices = dr.zeros(mi.Float, 6 * size * config.vertices_per_record)
        self.vertex_used = dr.zeros(mi.UInt32, size * config.vertices_per_record)

    # ---- keys ---------------------------------------------------------------------

    def _hashes(self, position: mi.Point3f, normal: mi.Vector3f) -> tuple[mi.UInt32, mi.UInt32]:
        cell = dr.floor(position / self.config.cell_size)
        parts = [mi.UInt32(mi.Int32(cell.x)), mi.UInt32(mi.Int32(cell.y)),
                 mi.UInt32(mi.Int32(cell.z)),
                 normal_bin(normal) if self.config.normal_bins else mi.UInt32(0)]
        slot, check = mi.UInt32(0), mi.UInt32(_GOLDEN)
        for part, prime in zip(parts, _PRIMES, strict=True):
            slot = _finalize(slot ^ (part * prime))
            check = _finalize(check + part * (prime | 1) + _GOLDEN)
        return slot & (self.config.table_size - 1), check | 1

    def find(self, position: mi.Point3f, normal: mi.Vector3f,
             active: mi.Bool = True, insert: bool = False) -> tuple[mi.UInt32, mi.Bool]:
        """The slot of the record of (position, normal) and whether there is one; with
        ``insert``, an empty slot on the probe sequence is claimed for it."""
        start, check = self._hashes(position, normal)
        mask = self.config.table_size - 1
        searching = mi.Bool(active)
        slot = mi.UInt32(0)
        found = mi.Bool(False)
        for probe in range(self.config.max_probes):
            index = (start + probe) & mask
            stored = dr.gather(mi.UInt32, self.keys, index, searching)
            hit = searching & (stored == check)
            if insert:
                empty = searching & (stored == 0)
                # Of the keys racing for this empty slot the largest checksum takes it,
                # whichever thread writes first (module doc, Reproducible).
                dr.scatter_reduce(dr.ReduceOp.Max, self.keys, check, index, empty)
                hit |= empty & (dr.gather(mi.UInt32, self.keys, index, empty) == check)
            slot = dr.select(hit, index, slot)
            found |= hit
            searching &= ~hit
        return slot, found

    def jittered(self, position: mi.Point3f, normal: mi.Vector3f,
                 sample: mi.Point2f) -> mi.Point3f:
        """Stochastic interpolation (Binder et al.): the lookup point moved by up to half
        a cell along the tangent plane, so neighbouring records blend in expectation."""
        frame = mi.Frame3f(normal)
        size = self.config.cell_size
        return position + (sample.x - 0.5) * size * frame.s + (sample.y - 0.5) * size * frame.t

    # ---- reading -------------------------------------------------------------------

    def lookup(self, position: mi.Point3f, normal: mi.Vector3f,
               sample: mi.Point2f | None = None, active: mi.Bool = True) -> GridValue:
        """The record at a point (jittered when the config asks and ``sample`` is
        given): rc, the average local variance and the average squared bias."""
        if self.config.jitter and sample is not None:
            position = self.jittered(position, normal, sample)
        slot, found = self.find(position, normal, active)
        found &= dr.gather(mi.Float, self.count, slot, found) > 0
        radiance = dr.gather(mi.Color3f, self.mean, slot, found)
        second = dr.gather(mi.Float, self.second, slot, found)
        marginal = dr.gather(mi.Float, self.marginal, slot, found)
        bias = dr.gather(mi.Float, self.bias, slot, found)
        deferred = dr.gather(mi.Float, self.deferred, slot, found)
        bias_known = found & (dr.gather(mi.Float, self.bias_count, slot, found) > 0)
        # Noisy estimates of non-negative quantities, read as at least 0.
        return GridValue(radiance, dr.maximum(second - marginal, 0.0),
                         dr.maximum(bias, 0.0), dr.maximum(deferred, 0.0), found, bias_known)

    # ---- writing -------------------------------------------------------------------

    def accumulate(self, slot: mi.UInt32, samples: mi.Color3f, active: mi.Bool,
                   deferred: mi.Float | None = None,
                   history: mi.Float | float | None = None) -> None:
        """Fold one pass into the records: ``samples`` holds K = ``samples_per_vertex``
        independent estimates Y per vertex, vertex-major (vertex v owns entries
        v K .. v K + K - 1), ``deferred`` (same layout; None: zeros) each sample's
        (f cos / p)^2 b^2 at its hit; ``slot`` and ``active`` are per vertex.

        Each vertex is one observation of the partition: its sample mean (for E[Y]), its
        mean of Y^2, its U-statistic for E[Y | y]^2 and its mean deferred bias. A
        record's running averages take the pass's n observations with weight
        min(1, n / min(count + n, H)), H = ``history`` (default ``max_history``; a
        Dr.Jit Float where a frozen pass takes it as an input). The squared bias is
        formed from this pass's observations first (module doc), from two on."""
        k = self.config.samples_per_vertex
        history = self.config.max_history if history is None else history
        luminance = mi.luminance(samples)
        sum_rgb = mi.Color3f(*(dr.block_sum(samples[c], k) for c in range(3)))
        sum_y = dr.block_sum(luminance, k)
        sum_y2 = dr.block_sum(dr.square(luminance), k)
        marginal = marginal_second_moment(sum_y, sum_y2, k)
        vertex_mean = sum_y / k

        size = self.config.table_size
        observations = dr.zeros(mi.UInt32, size)
        dr.scatter_add(observations, 1, slot, active)
        n = mi.Float(observations)
        # The pass's sums per record (module doc, Reproducible); the mean's channel c at
        # 3 slot + c, as its array holds it.
        batch_mean = sum(order_free_sum(sum_rgb[c] / k, 3 * slot + c, active, 3 * size)
                         for c in range(3))
        batch_second = order_free_sum(sum_y2 / k, slot, active, size)
        batch_marginal = order_free_sum(marginal, slot, active, size)
        # Sums of the vertices' means and of their squares: the products of distinct
        # vertices' means sum to (sum M)^2 - sum M^2.
        batch_y = order_free_sum(vertex_mean, slot, active, size)
        batch_y_sq = order_free_sum(dr.square(vertex_mean), slot, active, size)
        batch_deferred = (dr.zeros(mi.Float, size) if deferred is None else
                          order_free_sum(dr.block_sum(deferred, k) / k, slot, active, size))

        per_observation = dr.rcp(dr.maximum(n, 1.0))
        # [VTT24] Sec. 4.4: E[E[Y|y]^2] - E[Y]^2 within this pass; E[Y]^2 from the
        # n (n - 1) ordered pairs of distinct vertices.
        pairs = n * (n - 1.0)
        pass_bias = (batch_marginal * per_observation
                     - (dr.square(batch_y) - batch_y_sq) * dr.rcp(dr.maximum(pairs, 1.0)))
        self.bias, self.bias_count = _running(self.bias, self.bias_count, pass_bias,
                                              dr.select(pairs > 0, n, 0.0), history)

        weight = _weight(self.count, n, history)
        # New arrays, never a scatter into the grid's own: what a frozen pass returns.
        of_slot = dr.arange(mi.UInt32, 3 * size) // 3   # the mean's 3 floats per slot
        self.mean = dr.lerp(self.mean, batch_mean * dr.gather(mi.Float, per_observation,
                                                              of_slot),
                            dr.gather(mi.Float, weight, of_slot))
        self.second = dr.lerp(self.second, batch_second * per_observation, weight)
        self.marginal = dr.lerp(self.marginal, batch_marginal * per_observation, weight)
        self.deferred = dr.lerp(self.deferred, batch_deferred * per_observation, weight)
        self.count = dr.minimum(self.count + n, history)
        dr.eval(self.mean, self.second, self.marginal, self.deferred, self.count, self.bias,
                self.bias_count)

    def restart_history(self) -> None:
        """Start the long history from what the records hold now (a pre-fill's
        equilibrium): it stays in the averages as one observation, so no record is
        empty, and the next passes outweigh it."""
        self.count = dr.minimum(self.count, 1.0)
        self.bias_count = dr.minimum(self.bias_count, 1.0)
        dr.eval(self.count, self.bias_count)

    def mean_luminance(self) -> float:
        """The luminance of the records' radiance, averaged over the records that hold
        an estimate (0 where none does): the pre-fill's convergence measure."""
        held = self.count > 0
        luminance = mi.luminance(dr.gather(mi.Color3f, self.mean,
                                           dr.arange(mi.UInt32, self.config.table_size)))
        total = dr.sum(dr.select(held, luminance, 0.0), axis=None)
        records = dr.sum(dr.select(held, 1.0, 0.0), axis=None)
        return float(total[0]) / max(float(records[0]), 1.0)

    def store_vertices(self, slot: mi.UInt32, position: mi.Point3f, normal: mi.Vector3f,
                       choice: mi.Float, active: mi.Bool) -> None:
        """Keep (position, normal) as one of its record's representatives, in the place
        ``choice`` in [0, 1) picks (a later store there replaces it; of the lanes storing
        in one place the last lane's, whatever order threads write in)."""
        per_record = self.config.vertices_per_record
        place = slot * per_record + dr.minimum(mi.UInt32(choice * per_record), per_record - 1)
        lane = dr.arange(mi.UInt32, dr.width(place)) + 1
        claim = dr.zeros(mi.UInt32, self.most_places())
        dr.scatter_reduce(dr.ReduceOp.Max, claim, lane, place, active)
        won = active & (dr.gather(mi.UInt32, claim, place, active) == lane)
        dr.scatter(self.vertices, position, 2 * place, won)
        dr.scatter(self.vertices, normal, 2 * place + 1, won)
        dr.scatter(self.vertex_used, mi.UInt32(1), place, won)

    def records(self) -> int:
        """How many records hold an estimate."""
        return int(dr.sum(dr.select(self.count > 0, 1, 0), axis=None)[0])

    def places(self) -> mi.UInt32:
        """The places of every stored representative (a compaction: its width is read on
        the host)."""
        return dr.compress(self.vertex_used != 0)

    def most_places(self) -> int:
        """How many representatives the grid can hold."""
        return self.config.table_size * self.config.vertices_per_record

    def representatives(self, place: mi.UInt32 | None = None
                        ) -> tuple[mi.UInt32, mi.Point3f, mi.Vector3f]:
        """The representatives at ``place`` (default: every stored one, :meth:`places`):
        their records' slots, positions and normals."""
        place = self.places() if place is None else place
        slot = place // self.config.vertices_per_record
        position = dr.gather(mi.Point3f, self.vertices, 2 * place)
        normal = dr.gather(mi.Vector3f, self.vertices, 2 * place + 1)
        return slot, position, normal

    def lookup_arrays(self) -> dict[str, Any]:
        """The arrays a lookup reads (:data:`LOOKUP_ARRAYS`)."""
        return {name: getattr(self, name) for name in self.LOOKUP_ARRAYS}

    def bind_lookup(self, arrays: dict[str, Any]) -> None:
        """Look up ``arrays`` (:meth:`lookup_arrays` of this grid, as a frozen render
        received them) from now on."""
        for name in self.LOOKUP_ARRAYS:
            setattr(self, name, arrays[name])

    def arrays(self) -> dict[str, Any]:
        """Every array of the grid's state (:data:`ARRAYS`): what a frozen pass that
        writes the grid takes and returns."""
        return {name: getattr(self, name) for name in self.ARRAYS}

    def copied_arrays(self) -> dict[str, Any]:
        """:meth:`arrays` copied into new buffers (a frozen pass's replay writes into the
        arrays it is handed, whoever else holds them)."""
        copies = {name: dr.gather(type(array), array, dr.arange(mi.UInt32, dr.width(array)))
                  for name, array in self.arrays().items()}
        dr.eval(copies)
        return copies

    def bind(self, arrays: dict[str, Any]) -> None:
        """Hold ``arrays`` (:meth:`arrays` of this grid, e.g. a frozen pass's result)."""
        for name in self.ARRAYS:
            setattr(self, name, arrays[name])
