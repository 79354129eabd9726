"""Cache queries deferred out of the path loop: record where used, evaluate only those.

On the LLVM backend a masked SIMD lane still computes, so a cache query made
inside the symbolic path loop (``while dr.hint(active, ...)`` in path.py)
costs the hash grid and the MLP for *every* lane at *every* vertex, used or
not; so do the N_c BSDF samples of NIRC's cache term and the cache inputs
(textures, the BSDF's albedo). As in the NIRC paper's implementation (Sec.
4.5: the cache requests of a frame are gathered into buffers and the network
runs on those batches after path tracing), the render integrators instead
only *record* a cache vertex where its value is used, and do everything else
after the loop, on the recorded vertices only:

    loop:   at a cache vertex v of lane l (the k-th of the lane):
                ray(v) (o, d, maxt), beta_v, D_v           -> vertex slot  l K + k
            per query i >= D_v the loop knows (direction w_i, weight c_i):
                (w_i, c_i, used)                           -> query slot  (l K + k) Q + i
    after:  v = compress(recorded)                         (only the recorded vertices)
            x_v = intersect(ray(v)); inputs(x_v)           (the vertex, re-created)
            queries i < D_v drawn at x_v with rng(l, k, i)  -> query slots
            q = compress(used)                             (only the used queries)
            L_l += sum_{k, i} beta_v c_i n(x_v, w_i)       (a fixed order per lane)

c_i is the factor of n in the vertex's term: f_s cos / (p_s N_c) for L_c
(Eq. 12, whose N_c = D_v directions the deferred pass draws:
``QuerySource.drawn_query``), -f cos / p for the unbiased residual (Eq.
11, along the path's own continuation, known in the loop), NRC's
demodulation factor, NVC's g / N_c. Re-creating the vertex by intersecting
the recorded ray again gives the loop's surface interaction (the same ray,
the same scene), so the loop stores 11 floats per vertex instead of the
vertex's inputs and draws nothing for the cache.

Random numbers of the deferred draws: each lane draws a key from its sampler
before the loop (:func:`draw_query_key`, 48 random bits, hashed), and query
i of its k-th cache vertex draws from the PCG32 stream (key, k, i)
(:func:`query_rng`): reproducible for a given frame seed, independent of the
path's own samples and of where and in which order the draws happen (the
pass draws all (vertex, query) pairs as one wide kernel; the in-loop
fallback below draws the same numbers).

Buffer bound: fixed slots per lane, K vertices x Q queries (a
:class:`QueryLayout`), ``lanes * K * Q`` query slots (25 bytes each, +12 in
the deferred pass) and ``lanes * K`` vertex slots (45 bytes). K is an exact
bound for NRC (1: the path ends at its cache vertex) and unbiased NIRC
(len(nc)); a biased NIRC path ends at its cache vertex unless the
continuation is a delta lobe, so it has no finite bound with unbounded
depth: K starts at 1, and a frame in which some lane had more cache vertices
(the ``cache_vertices`` state counts them all, recorded or not) is traced
again with K = that count and the same random numbers (a clone of the
sampler taken before the loop), so no query is ever dropped. Q is the
largest N_c (+1 for the residual). A frame whose buffer would exceed
``cached.MAX_QUERY_SLOTS`` query slots allocates none: it draws and
evaluates its queries in the loop (:class:`InlineQueries`, masked, the cost
before deferral), with the same random numbers.

Fixed per-lane slots (rather than an atomic append counter) keep the result
bit-reproducible: the per-lane sum over slots runs in slot order
(``dr.block_reduce``), whereas appended queries land in a thread-dependent
order. The per-surface features (Sec. 4.5: hash grid, other surface
encodings, the first layer's surface columns) are computed once per recorded
vertex and gathered per query: measured with benchmarks/bench_queries.py
(16384 points, 2 shared cores, two runs), 1.0-1.1x, 1.2-1.4x, 1.3x faster
than recomputing them per query for N_c = 2, 4, 8; 1.4-1.6x slower at N_c =
1, where a vertex is a query, so one-slot layouts (NRC, biased N_c = 1)
compute them per query.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import drjit as dr
import mitsuba as mi

from renderers.integrators.path import Vertex


class QuerySource(Protocol):
    """What the deferred pass asks of the integrator whose queries it evaluates."""

    cache: Any
    #: The most queries a vertex draws itself (0: none; NIRC: the largest N_c).
    drawn_slots: int

    def surface_inputs(self, si: mi.SurfaceInteraction3f, bsdf: mi.BSDF) -> dict[str, Any]:
        """The per-surface cache inputs of a vertex (cached.cache_inputs)."""

    def drawn_query(self, si: mi.SurfaceInteraction3f, bsdf: mi.BSDF, rng: mi.PCG32,
                    slot: mi.UInt32, count: mi.UInt32) -> tuple[mi.Vector3f, mi.Spectrum, mi.Bool]:
        """Query ``slot`` (used where < ``count``) of a vertex that draws ``count``:
        (direction, weight, used), drawn with the query's own random numbers ``rng``."""


class QueryChannel(QuerySource, Protocol):
    """One cache's queries in a frame (``CachedPathIntegrator.query_channels``): the
    source of its queries, its buffer while the frame is traced (``queries``), the
    ``CacheState`` field counting its vertices (``counter``) and its layout, which
    grows with ``vertex_slots`` where it has no exact bound."""

    counter: str
    vertex_slots: int
    queries: QueryBuffer | InlineQueries | None

    def query_layout(self) -> QueryLayout:
        """Slots per lane of the channel's buffer."""


@dataclass(frozen=True)
class QueryLayout:
    """Slots of one lane: ``vertices`` cache vertices with ``queries`` queries each."""

    vertices: int
    queries: int

    @property
    def slots(self) -> int:
        return self.vertices * self.queries


@dataclass(frozen=True)
class QueryCount:
    """Cache queries evaluated by one deferred pass, and the slots it had."""

    queries: int
    lanes: int
    slots_per_lane: int


def draw_query_key(sampler: mi.Sampler) -> mi.UInt64:
    """Per lane, the key of the random numbers its cache vertices draw in the deferred
    pass: two of the lane's sampler dimensions (48 random bits), hashed."""
    u = sampler.next_2d()
    return mi.sample_tea_64(mi.UInt32(u.x * 0x1000000), mi.UInt32(u.y * 0x1000000))


def query_rng(key: mi.UInt64, index: mi.UInt32, slot: mi.UInt32 | int) -> mi.PCG32:
    """The random numbers of query ``slot`` of a lane's ``index``-th cache vertex: the
    PCG32 stream chosen by the lane's key, the vertex index and the slot alone, so
    the same wherever (in the loop or after it, in whatever order) it is drawn."""
    rng = mi.PCG32(max(dr.width(key), dr.width(index), dr.width(slot)))
    rng.seed(initstate=key, initseq=(mi.UInt64(index) << 32) | mi.UInt64(slot))
    return rng


def recreate_vertex(scene: mi.Scene, ray: mi.Ray3f) -> tuple[mi.SurfaceInteraction3f, mi.BSDF]:
    """The surface interaction and BSDF of the vertex ``ray`` found in the loop."""
    si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False)
    return si, si.bsdf(ray)


class QueryBuffer:
    """One frame's recorded cache vertices and queries (module doc), ``lanes`` wide;
    ``key``: each lane's :func:`draw_query_key` (needed where vertices draw queries)."""

    def __init__(self, lanes: int, layout: QueryLayout, key: mi.UInt64 | None = None) -> None:
        self.lanes, self.layout, self.key = lanes, layout, key
        n_vertices, n_queries = lanes * layout.vertices, lanes * layout.slots
        self.origin = dr.zeros(mi.Point3f, n_vertices)
        self.ray_direction = dr.zeros(mi.Vector3f, n_vertices)
        self.maxt = dr.zeros(mi.Float, n_vertices)
        self.beta = dr.zeros(mi.Spectrum, n_vertices)
        self.draws = dr.zeros(mi.UInt32, n_vertices)   # queries the vertex draws itself
        self.recorded = dr.zeros(mi.Bool, n_vertices)
        self.direction = dr.zeros(mi.Vector3f, n_queries)
        self.weight = dr.zeros(mi.Spectrum, n_queries)
        self.used = dr.zeros(mi.Bool, n_queries)
        self.lane = dr.arange(mi.UInt32, lanes)

    def vertex(self, index: mi.UInt32, vertex: Vertex, active: mi.Bool,
               inputs: dict[str, Any] | None = None) -> tuple[mi.UInt32, mi.Bool]:
        """Record the lane's ``index``-th cache vertex (the ray that found it and the
        throughput); returns its (slot, recorded) handle. ``inputs`` (what the loop
        computed already) is not stored: the deferred pass re-creates the vertex.

        A lane beyond the layout's vertices records nothing: the caller counts
        its cache vertices, and :meth:`CachedPathIntegrator.sample` retraces.
        """
        slot = self.lane * self.layout.vertices + index
        recorded = active & (index < self.layout.vertices)
        ray = vertex.ray
        dr.scatter(self.origin, ray.o, slot, recorded)
        dr.scatter(self.ray_direction, ray.d, slot, recorded)
        dr.scatter(self.maxt, ray.maxt, slot, recorded)
        dr.scatter(self.beta, mi.Spectrum(vertex.beta), slot, recorded)
        dr.scatter(self.recorded, True, slot, recorded)
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

    def draw(self, handle: tuple[mi.UInt32, mi.Bool], count: mi.UInt32,
             active: mi.Bool) -> mi.Spectrum:
        """Queries 0 .. count - 1 of a vertex are drawn by the deferred pass
        (``QuerySource.drawn_query``). Returns what to add now: nothing."""
        slot, recorded = handle
        dr.scatter(self.draws, mi.UInt32(count), slot, active & recorded)
        return mi.Spectrum(0)

    #: The buffer's Dr.Jit arrays (:meth:`arrays`): what a staged frame hands from one
    #: frozen pass to the next (renderers.methods.staged).
    ARRAYS = ("origin", "ray_direction", "maxt", "beta", "draws", "recorded", "direction",
              "weight", "used", "key")

    def arrays(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in self.ARRAYS}

    @classmethod
    def from_arrays(cls, lanes: int, layout: QueryLayout, arrays: dict[str, Any]) -> QueryBuffer:
        """The buffer of :meth:`arrays` (``lanes`` wide, ``layout``), for the deferred
        passes (not for recording: it has no ``lane``)."""
        buffer = cls.__new__(cls)
        buffer.lanes, buffer.layout = lanes, layout
        for name, value in arrays.items():
            setattr(buffer, name, value)
        return buffer

    def evaluate(self, scene: mi.Scene, source: QuerySource) -> tuple[mi.Spectrum, int]:
        """Per lane sum_q beta_v weight_q n(x_v, w_q) over the used queries only
        (width ``lanes``), and how many queries were evaluated: the two compactions
        (``dr.compress``, whose widths only the host knows) around the two passes."""
        vertices = dr.compress(self.recorded)
        if dr.width(vertices) == 0:
            return dr.zeros(mi.Spectrum, self.lanes), 0
        surface = self.vertex_pass(scene, source, vertices, *self.draw_lanes(source, vertices))
        index = dr.compress(self.used)
        if dr.width(index) == 0:
            return dr.zeros(mi.Spectrum, self.lanes), 0
        return (self.query_pass(source.cache, surface, compact_positions(self, vertices), index),
                dr.width(index))

    def draw_lanes(self, source: QuerySource, vertices: mi.UInt32) -> tuple[Any, Any]:
        """The lanes of the deferred draws (:meth:`vertex_pass`): one per (vertex, slot),
        slot-major, as (position in ``vertices``, slot); None where a vertex draws at
        most one query (a lane per vertex already). Built outside the pass: their width
        is the compressed count, which a frozen pass cannot read."""
        slots = source.drawn_slots
        if self.key is None or slots <= 1:
            return None, None
        count = dr.width(vertices)
        at = dr.arange(mi.UInt32, count * slots)
        return at % count, at // count

    def vertex_pass(self, scene: mi.Scene, source: QuerySource, vertices: mi.UInt32,
                    compact: mi.UInt32 | None, slot: mi.UInt32 | None) -> Any:
        """Re-create the recorded ``vertices`` (``dr.compress(recorded)``), draw their
        queries into the query slots and return their per-surface values: the cache
        inputs where a vertex has one slot, else the surface features (Sec. 4.5),
        computed once per vertex. Every size comes from its inputs' widths."""
        ray = mi.Ray3f(dr.gather(mi.Point3f, self.origin, vertices),
                       dr.gather(mi.Vector3f, self.ray_direction, vertices))
        ray.maxt = dr.gather(mi.Float, self.maxt, vertices)
        si, bsdf = recreate_vertex(scene, ray)
        inputs = source.surface_inputs(si, bsdf)
        if self.key is not None:
            self._draw_queries(source, si, bsdf, vertices, compact, slot)
        dr.eval(inputs, self.direction, self.weight, self.used)   # one kernel per vertex
        if self.layout.queries == 1:
            return inputs
        surface = source.cache.surface_features(**inputs)
        dr.eval(surface)   # once per vertex, before the per-query gathers
        return surface

    def query_pass(self, cache: Any, surface: Any, compact: mi.UInt32,
                   index: mi.UInt32) -> mi.Spectrum:
        """Per lane sum over the used queries ``index`` (``dr.compress(used)``) of
        beta_v weight_q n(x_v, w_q), in slot order; ``surface`` from :meth:`vertex_pass`,
        ``compact`` (:func:`compact_positions`) maps a vertex slot to its row."""
        vertex = index // self.layout.queries
        at = dr.gather(mi.UInt32, compact, vertex)
        if self.layout.queries == 1:   # a vertex is a query: its features per query
            features = cache.surface_features(
                **{name: dr.gather(type(value), value, at) for name, value in surface.items()})
        else:
            features = [dr.gather(type(row), row, at) for row in surface]
        n = cache.query(features, dr.gather(mi.Vector3f, self.direction, index))
        value = (mi.Spectrum(n) * dr.gather(mi.Spectrum, self.weight, index)
                 * dr.gather(mi.Spectrum, self.beta, vertex))
        per_slot = dr.zeros(mi.Spectrum, self.lanes * self.layout.slots)
        dr.scatter(per_slot, value, index)
        return dr.block_reduce(dr.ReduceOp.Add, per_slot, self.layout.slots)

    def _draw_queries(self, source: QuerySource, si: mi.SurfaceInteraction3f, bsdf: mi.BSDF,
                      vertices: mi.UInt32, compact: mi.UInt32 | None,
                      slot: mi.UInt32 | None) -> None:
        """The queries the recorded vertices draw (slots 0 .. draws - 1), into the query
        slots: one lane per (vertex, slot) (:meth:`draw_lanes`), so each buffer takes a
        single scatter (a second scatter into the same buffer would first launch a
        kernel for the first)."""
        if compact is None:   # a lane per vertex already
            vertex, slot = vertices, mi.UInt32(0)
        else:
            # Slot-major lanes: where vertices draw fewer than ``drawn_slots``, the unused
            # slots form whole SIMD packets, which the BSDF call skips.
            dr.eval(si, bsdf)   # per vertex, gathered per query
            vertex = dr.gather(mi.UInt32, vertices, compact)
            si = dr.gather(mi.SurfaceInteraction3f, si, compact)
            bsdf = dr.gather(mi.BSDFPtr, bsdf, compact)
        lane, index = vertex // self.layout.vertices, vertex % self.layout.vertices
        rng = query_rng(dr.gather(mi.UInt64, self.key, lane), index, slot)
        direction, weight, use = source.drawn_query(si, bsdf, rng, slot,
                                                    dr.gather(mi.UInt32, self.draws, vertex))
        query = vertex * self.layout.queries + slot
        dr.scatter(self.direction, direction, query, use)
        dr.scatter(self.weight, weight, query, use)
        dr.scatter(self.used, True, query, use)


def compact_positions(buffer: QueryBuffer, vertices: mi.UInt32) -> mi.UInt32:
    """Per vertex slot of ``buffer``, its row in ``vertices`` (the compressed recorded
    slots): where a query finds its vertex's surface values."""
    compact = dr.zeros(mi.UInt32, buffer.lanes * buffer.layout.vertices)
    dr.scatter(compact, dr.arange(mi.UInt32, dr.width(vertices)), vertices)
    return compact


class InlineQueries:
    """The same interface, evaluated where the query is made, inside the loop: for
    training paths (NRC self-training), whose targets need the value in the loop,
    and for render frames too large for a buffer. ``inputs``: the vertex's cache
    inputs where the loop does not pass them; ``source`` (with ``key``): the
    queries a vertex draws, with the same random numbers as in the deferred pass."""

    def __init__(self, cache: Any,
                 inputs: Callable[[mi.SurfaceInteraction3f, mi.BSDF], dict[str, Any]],
                 source: QuerySource | None = None, key: mi.UInt64 | None = None) -> None:
        self.cache, self.inputs, self.source, self.key = cache, inputs, source, key

    def vertex(self, index: mi.UInt32, vertex: Vertex, active: mi.Bool,
               inputs: dict[str, Any] | None = None) -> tuple[list[Any], Vertex, mi.UInt32]:
        if inputs is None:
            inputs = self.inputs(vertex.si, vertex.bsdf)
        return self.cache.surface_features(**inputs), vertex, index

    def add(self, handle: tuple[list[Any], Vertex, mi.UInt32], query: int,
            direction: mi.Vector3f, weight: mi.Spectrum, active: mi.Bool) -> mi.Spectrum:
        # A zero direction marks a lane whose value is discarded (an oracle skips it).
        n = self.cache.query(handle[0], dr.select(active, direction, mi.Vector3f(0)))
        return dr.select(active, mi.Spectrum(n) * weight, 0)

    def draw(self, handle: tuple[list[Any], Vertex, mi.UInt32], count: mi.UInt32,
             active: mi.Bool) -> mi.Spectrum:
        _, vertex, index = handle
        total = mi.Spectrum(0)
        for slot in range(self.source.drawn_slots):
            direction, weight, use = self.source.drawn_query(
                vertex.si, vertex.bsdf, query_rng(self.key, index, slot), mi.UInt32(slot),
                count)
            total += self.add(handle, slot, direction, weight, active & use)
        return total
