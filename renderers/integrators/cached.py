"""What the caching integrators share: cache inputs and the spread-tracking state.

`nirc` and `nrc` are the PT core plus cache terms; both need the per-surface
cache inputs of a vertex and the spread of the path so far (the SPH test,
spread.py), which this base keeps in the loop state.

Adaptive termination (NIRC paper Sec. 6.3): a per-pixel mask says where a
path may terminate into the cache at its first vertex v1. Mitsuba gives an
integrator no pixel coordinates, but its wavefront is laid out pixel-major
(the spp samples of a pixel are consecutive lanes, pixels in row-major order;
``tests/renderers/test_adaptive.py`` checks this layout), so the pixel of a
lane is ``lane // spp``.

Cache queries are deferred (deferred.py): the loop records the vertices whose
cache value is used in a per-frame :class:`~renderers.integrators.deferred.QueryBuffer`
per cache (``queries`` of each of :meth:`CachedPathIntegrator.query_channels`:
the integrator's own cache, and nvc_env.EnvVisibility's where a method adds one),
and :meth:`CachedPathIntegrator.sample` re-creates only those after the loop,
draws their sampled queries (NIRC's N_c directions), evaluates each cache and
adds the result to each lane's radiance before Mitsuba splats it to the film.
"""

from __future__ import annotations

from contextlib import AbstractContextManager, nullcontext
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from renderers.integrators.deferred import (
    InlineQueries,
    QueryBuffer,
    QueryChannel,
    QueryCount,
    QueryLayout,
    draw_query_key,
)
from renderers.integrators.path import PathIntegrator, Vertex
from renderers.integrators.spread import SPREAD_C, primary_footprint, spread_increment
from renderers.timing import StageTimer, synchronize

#: Floor of NRC's albedo demodulation factor: black surfaces would divide by 0.
MIN_DEMODULATION = 0.01
#: Query slots (lanes x slots per lane) above which a frame does not allocate the
#: deferred buffer (~37 bytes a slot with the deferred pass's temporaries: 1.2 GB)
#: and evaluates its queries in the loop instead, masked, as before deferral.
MAX_QUERY_SLOTS = 1 << 25


def cache_inputs(si: mi.SurfaceInteraction3f, bsdf: mi.BSDF,
                 specular: bool = False) -> dict[str, Any]:
    """Per-surface cache inputs: position, shading normal, roughness, diffuse albedo.

    Roughness is the BSDF's ``alpha`` where it has one; purely diffuse surfaces
    count as fully rough (1) — the cache encodes 1 - exp(-r) (NRC's mapping).
    The diffuse albedo is 0 on BSDFs without a diffuse lobe (Mitsuba's generic
    ``eval_diffuse_reflectance`` evaluates the BSDF at normal incidence, e.g. 25
    for a default rough conductor). With ``specular``, also the specular albedo
    ``albedo_spec`` (NRC's inputs): the BSDF's ``specular_reflectance``, whose
    Mitsuba default is 1 on BSDFs with a glossy or delta lobe when it is not set
    (the attribute then does not exist), and 0 on BSDFs without such a lobe.
    """
    flags = bsdf.flags()
    has_diffuse = mi.has_flag(flags, mi.BSDFFlags.Diffuse)
    has_specular = mi.has_flag(flags, mi.BSDFFlags.Glossy) | mi.has_flag(flags, mi.BSDFFlags.Delta)
    alpha = bsdf.eval_attribute_1("alpha", si)
    inputs = {
        "position": si.p,
        "normal": si.sh_frame.n,
        "roughness": dr.select(has_diffuse & ~mi.has_flag(flags, mi.BSDFFlags.Glossy), 1.0,
                               alpha),
        "albedo": dr.select(has_diffuse, bsdf.eval_diffuse_reflectance(si), 0.0),
    }
    if specular:
        inputs["albedo_spec"] = dr.select(
            bsdf.has_attribute("specular_reflectance"),
            bsdf.eval_attribute_3("specular_reflectance", si),
            dr.select(has_specular, 1.0, 0.0))
    return inputs


def demodulation(inputs: dict[str, Any]) -> mi.Color3f:
    """NRC's albedo demodulation factor: diffuse + specular albedo (floored)."""
    return dr.maximum(inputs["albedo"] + inputs["albedo_spec"], MIN_DEMODULATION)


class CacheState:
    """Per-path loop state of the caching estimators."""

    DRJIT_STRUCT = {
        "spread_sum": mi.Float,      # sum of sqrt spread terms (SPH, see spread.py)
        "a0": mi.Float,              # primary-vertex footprint a_0
        "cache_vertices": mi.UInt32, # vertices at which a cache term was added
        "env_vertices": mi.UInt32,   # vertices of a second query channel (nvc_env.EnvVisibility)
        "cache_depth": mi.UInt32,    # 1 + index of the vertex the path terminated into (0: none)
        "v1_allowed": mi.Bool,       # adaptive termination: this pixel may use the cache at v1
        "termination_value": mi.Float,  # a number the termination policy carries (termination/)
    }

    def __init__(self, spread_sum=None, a0=None, cache_vertices=None, env_vertices=None,
                 cache_depth=None, v1_allowed=None, termination_value=None):
        self.spread_sum = spread_sum
        self.a0 = a0
        self.cache_vertices = cache_vertices
        self.env_vertices = env_vertices
        self.cache_depth = cache_depth
        self.v1_allowed = v1_allowed
        self.termination_value = termination_value


class CachedPathIntegrator(PathIntegrator):
    """PT core that tracks the path spread and reports cache usage as AOVs.

    Properties: ``sph_c`` (c of the spread heuristic, default 0.01). The cache
    is attached after construction: ``integrator.cache = NeuralCache(...)``;
    the per-pixel v1 mask of adaptive termination by :meth:`set_v1_mask`
    (default: every pixel may use the cache at v1). AOVs: ``depth``,
    ``cache_depth`` (1 + index of the vertex a path terminated into the cache,
    0 for none) and ``cache_vertices``.

    Deferred queries (module doc): a subclass gives the buffer's
    :meth:`query_layout` and, where its cache vertices draw queries in the
    deferred pass (``drawn_slots``), :meth:`drawn_query`; the vertex's
    cache inputs are :meth:`surface_inputs`. Each :meth:`sample` appends a
    :class:`QueryCount` to ``query_counts`` (None for a frame above
    ``MAX_QUERY_SLOTS``, whose queries were drawn and evaluated in the loop)
    and, if ``timer`` is set, times the deferred pass (re-creating the
    vertices, drawing their queries, the cache) as the stage ``inference``
    (nested in the caller's ``render`` stage, which then excludes it). A
    method's frames run the same passes in stages instead
    (renderers.methods.staged), which append their own ``QueryCount``.
    """

    #: The most queries a cache vertex draws itself (``QueryBuffer.draw``; 0: none).
    drawn_slots = 0
    #: The ``CacheState`` field that counts this channel's cache vertices.
    counter = "cache_vertices"

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.sph_c = float(props.get("sph_c", SPREAD_C))
        self.cache: Any = None
        self.v1_mask: mi.Bool | None = None
        self.queries: QueryBuffer | InlineQueries | None = None   # while a frame is traced
        self.query_counts: list[QueryCount | None] = []
        self.timer: StageTimer | None = None
        # Cache vertices per lane a buffer holds where no exact bound exists
        # (biased NIRC); raised to what a frame needed, kept for later frames.
        self.vertex_slots = 1
        # Set while a staged frame renders (renderers.methods.staged).
        self.staged: Any = None

    def frame_freezable(self) -> bool:
        """Whether the stages of a frame (renderers.methods.staged) may be frozen: the
        core's condition, and every channel's cache hands over the arrays its queries
        read (``inference_state``; a test's oracle may not)."""
        return super().frame_freezable() and all(
            hasattr(channel.cache, "inference_state") for channel in self.query_channels())

    def frame_state(self, scene: mi.Scene) -> dict[str, Any]:
        return {**super().frame_state(scene), "v1_mask": self.v1_mask}

    def bind_frame_state(self, scene: mi.Scene, state: dict[str, Any]) -> None:
        super().bind_frame_state(scene, state)
        self.v1_mask = state["v1_mask"]

    def set_v1_mask(self, mask: np.ndarray | None) -> None:
        """Per-pixel (H, W) booleans: where paths may terminate into the cache at v1.

        The mask is a memory-backed array, so changing it does not recompile
        the render kernel. None allows every pixel.
        """
        if mask is None:
            self.v1_mask = None
            return
        mask = np.asarray(mask, dtype=bool)
        if mask.ndim != 2:
            raise ValueError(f"the v1 mask must be (height, width), got shape {mask.shape}")
        self.v1_mask = mi.Bool(mask.ravel())
        dr.eval(self.v1_mask)

    def aov_names(self) -> list[str]:
        return ["depth", "cache_depth", "cache_vertices"]

    def query_layout(self) -> QueryLayout:
        """Slots per lane of the frame's query buffer (deferred.py)."""
        raise NotImplementedError

    def surface_inputs(self, si: mi.SurfaceInteraction3f, bsdf: mi.BSDF) -> dict[str, Any]:
        """The cache inputs of a vertex (:func:`cache_inputs`)."""
        return cache_inputs(si, bsdf)

    def drawn_query(self, si: mi.SurfaceInteraction3f, bsdf: mi.BSDF, rng: mi.PCG32,
                    slot: mi.UInt32, count: mi.UInt32) -> tuple[mi.Vector3f, mi.Spectrum, mi.Bool]:
        """Query ``slot`` of a cache vertex that draws ``count`` (``drawn_slots``; deferred.py)."""
        raise NotImplementedError

    def query_channels(self) -> list[QueryChannel]:
        """The caches whose queries a frame records, each in its own buffer: by
        default the integrator's own (counted by ``CacheState.cache_vertices``)."""
        return [self]

    def sample(self, scene, sampler, ray, medium=None, active=True):
        """Trace the paths, recording cache queries; then evaluate the recorded ones.

        In a staged frame (renderers.methods.staged) the same render is cut in two:
        with ``staged.recording`` it only traces and records (the buffers and the most
        cache vertices a lane had are left in ``staged.recorded``); with
        ``staged.lane_values`` it traces nothing and returns those per-lane values,
        which the film then splats with the same samples as the traced render."""
        staged = self.staged
        if staged is not None and staged.lane_values is not None:
            zero = mi.Float(0)
            lane = dr.arange(mi.UInt32, dr.width(ray.d.x))
            return (dr.gather(mi.Spectrum, staged.lane_values, lane), mi.Bool(False),
                    [zero, zero, zero])
        lanes = dr.width(ray.d.x)
        channels = self.query_channels()
        layouts = [channel.query_layout() for channel in channels]
        keys = [draw_query_key(sampler) if channel.drawn_slots else None
                for channel in channels]
        replay = sampler.clone()  # the same random numbers, should a buffer be too small
        while True:
            deferred = lanes * sum(layout.slots for layout in layouts) <= MAX_QUERY_SLOTS
            for channel, layout, key in zip(channels, layouts, keys, strict=True):
                channel.queries = (QueryBuffer(lanes, layout, key) if deferred else
                                   InlineQueries(channel.cache, channel.surface_inputs,
                                                 channel, key))
            L, valid_ray, depth, state = self.trace(scene, sampler, ray, active)
            if staged is not None and staged.recording:
                # The most cache vertices of a lane, on the device: the host reads it
                # after the frozen pass (a read-back inside would re-record it).
                staged.recorded = [(channel.queries.arrays(),
                                    dr.max(getattr(state, channel.counter), axis=None))
                                   for channel in channels]
                return self._finish(channels, L, valid_ray, depth, state, None)
            synchronize(L, valid_ray, depth, state)
            needed = [int(dr.max(getattr(state, channel.counter), axis=None)[0])
                      for channel in channels]
            if not deferred or all(n <= layout.vertices
                                   for n, layout in zip(needed, layouts, strict=True)):
                break
            # Some lane had more cache vertices than slots: trace the frame again
            # with the same random numbers and room for all of them.
            layouts = self.grow_layouts(channels, needed)
            sampler = replay.clone()
        count = None
        if deferred:
            with self._stage("inference"):
                queries = 0
                for channel, n in zip(channels, needed, strict=True):
                    if n:   # else no lane recorded a vertex of this channel: nothing to add
                        cached, evaluated = channel.queries.evaluate(scene, channel)
                        L, queries = mi.Spectrum(L) + cached, queries + evaluated
                synchronize(L)
            count = QueryCount(queries, lanes, sum(layout.slots for layout in layouts))
        return self._finish(channels, L, valid_ray, depth, state, count)

    def _finish(self, channels: list[QueryChannel], L: mi.Spectrum, valid_ray: mi.Bool,
                depth: mi.UInt32, state: CacheState, count: QueryCount | None) -> tuple:
        for channel in channels:
            channel.queries = None
        if self.staged is None or not self.staged.recording:
            self.query_counts.append(count)
        return L, valid_ray, [mi.Float(depth), mi.Float(state.cache_depth),
                              mi.Float(state.cache_vertices)]

    @staticmethod
    def grow_layouts(channels: list[QueryChannel], needed: list[int]) -> list[QueryLayout]:
        """Raise the vertex slots of every channel some lane of which had ``needed`` cache
        vertices, more than its layout held; the new layouts."""
        for channel, n in zip(channels, needed, strict=True):
            if n > channel.query_layout().vertices:
                channel.vertex_slots = n
        layouts = [channel.query_layout() for channel in channels]
        for channel, n, layout in zip(channels, needed, layouts, strict=True):
            if layout.vertices < n:
                raise RuntimeError(f"a path used the cache at {n} vertices, more than the "
                                   f"bound {layout.vertices} of {type(channel).__name__}")
        return layouts

    def _stage(self, name: str) -> AbstractContextManager[None]:
        return self.timer.stage(name) if self.timer is not None else nullcontext()

    def init_state(self, ray: mi.Ray3f, sampler: mi.Sampler) -> CacheState:
        state = new_cache_state()
        if self.v1_mask is not None:
            pixel = pixel_index(ray, sampler)
            if dr.width(pixel) != dr.width(self.v1_mask) * sampler.sample_count():
                raise ValueError(f"v1 mask has {dr.width(self.v1_mask)} pixels; the film has "
                                 f"{dr.width(pixel) // sampler.sample_count()}")
            state.v1_allowed = dr.gather(mi.Bool, self.v1_mask, pixel)
        return state

    def after_emission(self, vertex: Vertex, state: CacheState) -> CacheState:
        return update_spread(vertex, state)


# Functions rather than methods: Mitsuba's (nanobind) integrator classes cannot
# be combined by multiple inheritance, so e.g. NRC's self-training paths (a
# training integrator) reuse these by calling them.

def new_cache_state() -> CacheState:
    return CacheState(mi.Float(0), mi.Float(0), mi.UInt32(0), mi.UInt32(0), mi.UInt32(0),
                      mi.Bool(True), mi.Float(0))


def smooth_context() -> mi.BSDFContext:
    """A BSDF context restricted to the smooth (non-delta) lobes."""
    ctx = mi.BSDFContext()
    ctx.type_mask = int(mi.BSDFFlags.Smooth)
    return ctx


def pixel_index(ray: mi.Ray3f, sampler: mi.Sampler) -> mi.UInt32:
    """Row-major film pixel of each lane of a Mitsuba render wavefront (module doc)."""
    return dr.arange(mi.UInt32, dr.width(ray.d.x)) // sampler.sample_count()


def update_spread(vertex: Vertex, state: CacheState) -> CacheState:
    """Add the vertex to the path's spread (SPH, spread.py); a_0 at the first vertex.

    A segment that follows a delta BSDF sample adds nothing: a mirror or a
    smooth dielectric does not widen the footprint (NRC treats a Dirac bounce
    as zero spread), while Mitsuba reports such a sample with pdf 1, which
    would add sqrt(d^2 / |cos|).
    """
    si = vertex.si
    distance_sq = dr.square(si.t)
    cos_theta = dr.dot(si.sh_frame.n, -vertex.ray.d)
    first = vertex.depth == 0
    state.a0 = dr.select(first & vertex.active, primary_footprint(distance_sq, cos_theta),
                         state.a0)
    increment = spread_increment(distance_sq, vertex.prev_bsdf_pdf, cos_theta)
    grow = (~first & ~vertex.prev_bsdf_delta & vertex.active & si.is_valid()
            & dr.isfinite(increment))
    state.spread_sum = dr.select(grow, state.spread_sum + increment, state.spread_sum)
    return state
