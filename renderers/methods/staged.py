"""A caching integrator's frame as frozen stages (docs/timing.md, "Frozen frames").

A caching integrator's render (renderers.integrators.cached) records its cache
vertices and queries while it traces, then compacts them twice with
``dr.compress``, whose width only the host knows: a frozen function that
compresses and then reduces records again on every call, and a width read on the
host inside one is baked into its recording. So the frame is cut at both
compactions, each pass frozen on its own, every size inside a pass taken from its
inputs' widths (the compacted widths and the lanes built from them are arguments):

    trace    mi.render with the integrator recording only: the path image, the
             query buffers, the most cache vertices of a lane           (frozen)
    host     the most cache vertices read back; more than the buffer held: trace
             again with room for them (a new recording, once);
             vertices = compress(recorded)
    vertex   re-create the vertices, draw their queries, surface features (frozen)
    host     index = compress(used)
    query    evaluate the cache, sum per lane in slot order           (frozen)
    splat    mi.render again with the same seed: the film samples the same
             positions and splats each lane's cache sum; added to the path image
                                                                      (frozen)

The film is linear in the values splatted at the same positions, so the image
is the one the integrator's own ``sample`` gives (one splat of path + cache), up
to float rounding. Frozen or not (``frozen_frames``), a method's frames run these
stages, so the two give bitwise equal images. Trace is timed as ``render``, the
rest as ``inference``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi

from renderers.frozen import Capacity, Frozen, freezing, padded, weak_method
from renderers.integrators.cached import MAX_QUERY_SLOTS
from renderers.integrators.deferred import (
    QueryBuffer,
    QueryChannel,
    QueryCount,
    QueryLayout,
    compact_positions,
)
from renderers.timing import StageTimer, kernel_history_enabled, synchronize


@dataclass
class StagedPass:
    """What the integrator's ``sample`` reads and leaves while a staged pass renders."""

    recording: bool = False
    #: Per channel, (buffer arrays, most cache vertices of a lane) of the trace.
    recorded: list[tuple[dict[str, Any], Any]] | None = None
    #: Per lane, the value the splat pass returns.
    lane_values: Any = None


def inference_state(cache: Any) -> dict[str, Any] | None:
    """The Dr.Jit arrays a cache's queries read (None: it has none to hand over)."""
    state = getattr(cache, "inference_state", None)
    return None if state is None else state()


class ChannelPasses:
    """The vertex and query passes of one query channel, frozen or not.

    Frozen, the compacted vertices and queries enter their pass padded to a
    :class:`renderers.frozen.Capacity` per buffer layout (a frozen call records once
    per width it is given, so a width that changed every frame would record every
    frame). The extra lanes repeat the last vertex or query, whose work writes the
    same values to the same slots, so the image is unchanged."""

    def __init__(self, channel: QueryChannel, frozen: bool) -> None:
        self.channel, self.frozen = channel, frozen
        wrap = (lambda fn: Frozen(fn, auto_opaque=False)) if frozen else (lambda fn: fn)
        self.vertex = wrap(weak_method(self._vertex))
        self.query = wrap(weak_method(self._query))
        #: Per buffer layout, the capacities of the vertices and of the queries.
        self._capacity: dict[tuple[int, int, int], tuple[Capacity, Capacity]] = {}

    def evaluate(self, scene: mi.Scene, buffer: QueryBuffer) -> tuple[mi.Spectrum | None, int]:
        """The channel's per-lane cache sums (None: no query) and the queries evaluated."""
        state = inference_state(self.channel.cache)
        layout = (buffer.lanes, buffer.layout.vertices, buffer.layout.queries)
        vertices = dr.compress(buffer.recorded)
        if dr.width(vertices) == 0:
            return None, 0
        if self.frozen:
            vertex_capacity, query_capacity = self._capacity.setdefault(
                layout, (Capacity(buffer.lanes), Capacity(buffer.lanes)))
            vertices = padded(vertices, vertex_capacity.fit(
                dr.width(vertices), buffer.lanes * buffer.layout.vertices))
        compact, slot = buffer.draw_lanes(self.channel, vertices)
        try:
            surface, used, direction, weight = self.vertex(
                scene, state, buffer.arrays(), vertices, compact, slot, layout)
            index = dr.compress(used)
            count = dr.width(index)
            if count == 0:
                return None, 0
            if self.frozen:
                index = padded(index, query_capacity.fit(count, buffer.lanes
                                                          * buffer.layout.slots))
            values = self.query(state, surface, compact_positions(buffer, vertices), index,
                                direction, weight, buffer.beta, layout)
        finally:
            self._bind(state)   # a recording bound the cache to its own inputs
        return values, count

    def _bind(self, state: dict[str, Any] | None) -> None:
        if state is not None:
            self.channel.cache.bind_inference(state)

    def _vertex(self, scene: mi.Scene, state: dict[str, Any] | None, arrays: dict[str, Any],
                vertices: mi.UInt32, compact: mi.UInt32 | None, slot: mi.UInt32 | None,
                layout: tuple[int, int, int]) -> tuple[Any, ...]:
        self._bind(state)
        lanes, *shape = layout
        buffer = QueryBuffer.from_arrays(lanes, QueryLayout(*shape), arrays)
        surface = buffer.vertex_pass(scene, self.channel, vertices, compact, slot)
        return surface, buffer.used, buffer.direction, buffer.weight

    def _query(self, state: dict[str, Any] | None, surface: Any, compact: mi.UInt32,
               index: mi.UInt32, direction: mi.Vector3f, weight: mi.Spectrum, beta: mi.Spectrum,
               layout: tuple[int, int, int]) -> mi.Spectrum:
        self._bind(state)
        lanes, *shape = layout
        buffer = QueryBuffer.from_arrays(lanes, QueryLayout(*shape),
                                         {"direction": direction, "weight": weight,
                                          "beta": beta})
        return buffer.query_pass(self.channel.cache, surface, compact, index)


class StagedRender:
    """A caching integrator's frame (module doc): a :data:`FrameFn` timed as 'render'
    (the trace) and 'inference' (the rest); frozen where freezing is on and the
    integrator says its frame can be (``frame_freezable()``)."""

    def __init__(self, scene: Any, integrator: Any, spp: int) -> None:
        self.scene, self.integrator, self.spp = scene.scene, integrator, spp
        width, height = scene.resolution
        self.lanes = width * height * spp
        frozen = freezing() and integrator.frame_freezable()
        wrap = Frozen if frozen else (lambda fn: fn)
        self.trace = wrap(weak_method(self._trace))
        self.splat = wrap(weak_method(self._splat))
        self.channels = [ChannelPasses(channel, frozen)
                         for channel in integrator.query_channels()]
        #: Recordings made in frames whose buffers grew (a lane had more cache vertices
        #: than any before): new layouts record every pass anew, by design.
        self.growth_recordings = 0
        #: (kernel history on, vertex slots per channel) of the frames so far: a frozen
        #: pass records anew under each flag, so a layout is new per flag.
        self._met: set[tuple[bool, tuple[int, ...]]] = set()

    def recordings(self) -> int | None:
        frozen = [self.trace, self.splat, *(f for c in self.channels for f in (c.vertex, c.query))]
        counts = [f.recordings() for f in frozen if isinstance(f, Frozen)]
        return sum(counts) if counts else None

    def __call__(self, _index: int, seed: int, timer: StageTimer) -> Any:
        integrator, scene = self.integrator, self.scene
        channels = integrator.query_channels()
        layouts = [channel.query_layout() for channel in channels]
        if self.lanes * sum(layout.slots for layout in layouts) > MAX_QUERY_SLOTS:
            # Too large a buffer: the integrator evaluates its queries in the loop.
            integrator.timer = timer
            with timer.stage("render"):
                image = mi.render(scene, integrator=integrator, spp=self.spp, seed=seed)
                synchronize(image)
            return image
        state = integrator.frame_state(scene)
        history = kernel_history_enabled()
        recordings_before = self.recordings()
        grew = (history, tuple(layout.vertices for layout in layouts)) not in self._met
        with timer.stage("render"):
            while True:
                image, recorded = self.trace(scene, mi.UInt32(seed), state,
                                             tuple(layout.vertices for layout in layouts))
                integrator.bind_frame_state(scene, state)   # a recording bound its inputs
                needed = [int(most[0]) for _, most in recorded]
                if all(n <= layout.vertices for n, layout in zip(needed, layouts, strict=True)):
                    break
                # Some lane had more cache vertices than slots: trace again with room.
                layouts, grew = integrator.grow_layouts(channels, needed), True
            synchronize(image)
        self._met.add((history, tuple(layout.vertices for layout in layouts)))
        with timer.stage("inference"):
            total, queries = None, 0
            for passes, layout, (arrays, _), n in zip(self.channels, layouts, recorded, needed,
                                                      strict=True):
                if not n:   # no lane recorded a vertex of this channel
                    continue
                values, count = passes.evaluate(scene, QueryBuffer.from_arrays(
                    self.lanes, layout, arrays))
                if values is not None:
                    total, queries = values if total is None else total + values, queries + count
            if total is not None:
                image = self.splat(scene, mi.UInt32(seed), image, total)
            synchronize(image)
        integrator.query_counts.append(
            QueryCount(queries, self.lanes, sum(layout.slots for layout in layouts)))
        if grew and recordings_before is not None:
            self.growth_recordings += self.recordings() - recordings_before
        return image

    def _trace(self, scene: mi.Scene, seed: mi.UInt32, state: dict[str, Any],
               _vertex_slots: tuple[int, ...]) -> tuple[Any, list[Any]]:
        """The path image and the recorded buffers; ``_vertex_slots`` keys the recording
        (the buffers' size)."""
        integrator = self.integrator
        integrator.bind_frame_state(scene, state)
        integrator.staged = StagedPass(recording=True)
        try:
            image = mi.render(scene, integrator=integrator, spp=self.spp, seed=seed)
            return image, integrator.staged.recorded
        finally:
            integrator.staged = None

    def _splat(self, scene: mi.Scene, seed: mi.UInt32, image: Any, values: mi.Spectrum) -> Any:
        """``image`` plus the film of ``values`` per lane, splatted at the positions the
        trace sampled with ``seed``."""
        integrator = self.integrator
        integrator.staged = StagedPass(lane_values=values)
        try:
            return image + mi.render(scene, integrator=integrator, spp=self.spp, seed=seed)
        finally:
            integrator.staged = None
