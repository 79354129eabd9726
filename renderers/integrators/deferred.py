"""Cache queries deferred out of the path loop: record where used, evaluate only those.

On the LLVM backend a masked SIMD lane still computes, so a cache query made
inside the symbolic path loop (``while dr.hint(active, ...)`` in path.py)
costs the hash grid and the MLP for *every* lane at *every* vertex, used or
not. As in the NIRC paper's implementation (Sec. 4.5: the cache requests of a
frame are gathered into buffers and the network runs on those batches after
path tracing), the render integrators instead only *record* a query where its
value is used, and evaluate the recorded ones after the loop:

    loop:   at a cache vertex v of lane l (the k-th of the lane):
                inputs(v), beta_v                      -> vertex slot  l K + k
            per query i of v (direction w_i, weight c_i):
                (w_i, c_i, used)                       -> query slot  (l K + k) Q + i
    after:  q = compress(used)                         (only the used queries)
            L_l += sum_{k, i} beta_v c_i n(x_v, w_i)   (a fixed order per lane)

c_i is the factor of n in the vertex's term: f_s cos / (p_s N_c) for L_c
(Eq. 12), -f cos / p for the unbiased residual (Eq. 11), NRC's demodulation
factor. The random numbers (the N_c directions) are drawn in the loop as
before, so the estimator is the same; only the summation order differs.

Buffer bound: fixed slots per lane, K vertices x Q queries (a
:class:`QueryLayout`), ``lanes * K * Q`` query slots (25 bytes each, +12 in
the deferred pass) and ``lanes * K`` vertex slots (52 bytes, NRC 64). K is
an exact bound for NRC (1: the path ends at its cache vertex) and unbiased
NIRC (len(nc)); a biased NIRC path ends at its cache vertex unless the continuation is a delta
lobe, so it has no finite bound with unbounded depth: K starts at 1, and a
frame in which some lane had more cache vertices (the ``cache_vertices``
state counts them all, recorded or not) is traced again with K = that count
and the same random numbers (a clone of the sampler taken before the loop),
so no query is ever dropped. Q is the largest N_c (+1 for the residual).
A frame whose buffer would exceed ``cached.MAX_QUERY_SLOTS`` query slots
allocates none: it evaluates its queries in the loop (:class:`InlineQueries`,
masked, the cost before deferral).

Fixed per-lane slots (rather than an atomic append counter) keep the result
bit-reproducible: the per-lane sum over slots runs in slot order
(``dr.block_reduce``), whereas appended queries land in a thread-dependent
order. The surface inputs are stored once per vertex. The per-surface
features (Sec. 4.5: hash grid, other surface encodings, the first layer's
surface columns) are computed once per used vertex and gathered per query:
measured with benchmarks/bench_queries.py (16384 points, 2 shared cores, two
runs), 1.0-1.1x, 1.2-1.4x, 1.3x faster than recomputing them per query for
N_c = 2, 4, 8; 1.4-1.6x slower at N_c = 1, where a vertex is a query, so
one-slot layouts (NRC, biased N_c = 1) compute them per query.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi

from renderers.integrators.path import Vertex

#: The per-surface cache inputs a vertex slot stores (cached.cache_inputs) and their types.
INPUT_TYPES = {"position": mi.Point3f, "normal": mi.Vector3f, "roughness": mi.Float,
               "albedo": mi.Color3f}


@dataclass(frozen=True)
class QueryLayout:
    """Slots of one lane: ``vertices`` cache vertices with ``queries`` queries each;
    ``specular``: the vertices store NRC's specular albedo too."""

    vertices: int
    queries: int
    specular: bool = False

    @property
    def slots(self) -> int:
        return self.vertices * self.queries


@dataclass(frozen=True)
class QueryCount:
    """Cache queries evaluated by one deferred pass, and the slots it had."""

    queries: int
    lanes: int
    slots_per_lane: int


class QueryBuffer:
    """One frame's recorded cache queries (module doc), ``lanes`` wide."""

    def __init__(self, lanes: int, layout: QueryLayout) -> None:
        self.lanes, self.layout = lanes, layout
        types = {**INPUT_TYPES, "albedo_spec": mi.Color3f} if layout.specular else INPUT_TYPES
        n_vertices, n_queries = lanes * layout.vertices, lanes * layout.slots
        self.inputs = {name: dr.zeros(cls, n_vertices) for name, cls in types.items()}
        self.beta = dr.zeros(mi.Spectrum, n_vertices)
        self.direction = dr.zeros(mi.Vector3f, n_queries)
        self.weight = dr.zeros(mi.Spectrum, n_queries)
        self.used = dr.zeros(mi.Bool, n_queries)
        self.lane = dr.arange(mi.UInt32, lanes)

    def vertex(self, index: mi.UInt32, vertex: Vertex, inputs: dict[str, Any],
               active: mi.Bool) -> tuple[mi.UInt32, mi.Bool]:
        """Record the lane's ``index``-th cache vertex; returns its (slot, recorded) handle.

        A lane beyond the layout's vertices records nothing: the caller counts
        its cache vertices, and :meth:`CachedPathIntegrator.sample` retraces.
        """
        slot = self.lane * self.layout.vertices + index
        recorded = active & (index < self.layout.vertices)
        for name, buffer in self.inputs.items():
            dr.scatter(buffer, type(buffer)(inputs[name]), slot, recorded)
        dr.scatter(self.beta, mi.Spectrum(vertex.beta), slot, recorded)
        return slot, recorded

    def add(self, handle: tuple[mi.UInt32, mi.Bool], query: int, direction: mi.Vector3f,
            weight: mi.Spectrum, active: mi.Bool) -> mi.Spectrum:
        """Record query ``query`` of a vertex: n(x, direction) enters the lane's radiance
        as beta * weight * n after the loop. Returns what to add now: nothing."""
        slot, recorded = handle
        slot = slot * self.layout.queries + query
        active = active & recorded
        dr.scatter(self.direction, mi.Vector3f(direction), slot, active)
        dr.scatter(self.weight, mi.Spectrum(weight), slot, active)
        dr.scatter(self.used, True, slot, active)
        return mi.Spectrum(0)

    def evaluate(self, cache: Any) -> tuple[mi.Spectrum, int]:
        """Per lane sum_q beta_v weight_q n(x_v, w_q) over the recorded queries only
        (width ``lanes``), and how many queries were evaluated."""
        index = dr.compress(self.used)
        count = dr.width(index)
        if count == 0:
            return dr.zeros(mi.Spectrum, self.lanes), 0
        vertex = index // self.layout.queries
        n = cache.query(self._surface_features(cache, vertex),
                        dr.gather(mi.Vector3f, self.direction, index))
        value = (mi.Spectrum(n) * dr.gather(mi.Spectrum, self.weight, index)
                 * dr.gather(mi.Spectrum, self.beta, vertex))
        per_slot = dr.zeros(mi.Spectrum, self.lanes * self.layout.slots)
        dr.scatter(per_slot, value, index)
        return dr.block_reduce(dr.ReduceOp.Add, per_slot, self.layout.slots), count


    def _surface_features(self, cache: Any, vertex: mi.UInt32) -> list[Any]:
        """The per-surface features (Sec. 4.5) of each query's vertex ``vertex``:
        computed once per used vertex and gathered per query, or directly per query
        where a vertex has a single slot (then a vertex is a query)."""
        if self.layout.queries == 1:
            return cache.surface_features(**self._inputs_at(vertex))
        used = dr.zeros(mi.Bool, self.lanes * self.layout.vertices)
        dr.scatter(used, True, vertex)
        vertices = dr.compress(used)
        compact = dr.zeros(mi.UInt32, self.lanes * self.layout.vertices)
        dr.scatter(compact, dr.arange(mi.UInt32, dr.width(vertices)), vertices)
        surface = cache.surface_features(**self._inputs_at(vertices))
        dr.eval(surface)   # once per vertex, before the per-query gathers
        at = dr.gather(mi.UInt32, compact, vertex)
        return [dr.gather(type(row), row, at) for row in surface]

    def _inputs_at(self, vertex: mi.UInt32) -> dict[str, Any]:
        return {name: dr.gather(type(buffer), buffer, vertex)
                for name, buffer in self.inputs.items()}


class InlineQueries:
    """The same interface, evaluated where the query is made, inside the loop: for
    training paths (NRC self-training), whose targets need the value in the loop,
    and for render frames too large for a buffer."""

    def __init__(self, cache: Any) -> None:
        self.cache = cache

    def vertex(self, index: mi.UInt32, vertex: Vertex, inputs: dict[str, Any],
               active: mi.Bool) -> list[Any]:
        return self.cache.surface_features(**inputs)

    def add(self, surface: list[Any], query: int, direction: mi.Vector3f, weight: mi.Spectrum,
            active: mi.Bool) -> mi.Spectrum:
        # A zero direction marks a lane whose value is discarded (an oracle skips it).
        n = self.cache.query(surface, dr.select(active, direction, mi.Vector3f(0)))
        return dr.select(active, mi.Spectrum(n) * weight, 0)
