"""The update (propagation) pass of the hashed-grid moment cache ([VTT24] Sec. 5;
docs/references.md, docs/variance_trading.md).

At every representative vertex y of the grid (:class:`~renderers.caches.moment_grid.MomentGrid`)
the pass draws K independent one-segment estimates of the light y reflects, with the
path tracer's own sampling — it *is* the core loop (:class:`PathIntegrator`), run from
y for one segment:

    Y = NEE(y) w_light  +  (f cos / p)(y -> x) [Le(x) w_bsdf + rc(x)]

NEE and the BSDF sample at y are MIS-weighted as in every path (the same light
selection object), and at the vertex x the BSDF sample reaches the path stops with
the cache's value rc(x) (the grid's reflected radiance there, looked up as the path
tracer looks it up). E[Y | y] is the light y reflects with the cache standing in for
what lies beyond x, so repeated passes propagate radiance one bounce per frame
(iterative, as the paper's pass). y's own emission is not part of Y.

The pass then folds the K samples of every vertex into its record
(:meth:`MomentGrid.accumulate`) and keeps hit vertices x as representatives of their
cells (inserting records for cells not seen yet) with probability ``hit_store_probability``
per sample, so the grid explores the scene. Caches hold reflected radiance for diffuse
surfaces (no outgoing direction): the paper uses diffuse materials only.
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi

from renderers.caches.moment_grid import MomentGrid
from renderers.integrators import register
from renderers.integrators.path import PathIntegrator, Vertex, VertexTerms

UPDATE_PLUGIN_NAME = "nirc_grid_update"

#: Offset of the ray that re-finds a stored vertex, as a share of the scene's extent.
RECOVERY_OFFSET = 1e-4


class UpdateState:
    """Per-sample state of the update pass."""

    DRJIT_STRUCT = {
        "emitted": mi.Spectrum,   # y's own emission, which the core gathers first
        "found": mi.Bool,         # the ray re-found y (its first vertex)
        "hit_p": mi.Point3f,      # the vertex x the BSDF sample reached
        "hit_n": mi.Vector3f,
        "hit": mi.Bool,
        "deferred": mi.Float,     # (f cos / p)^2 b^2(x): the deferred squared bias
    }

    def __init__(self, emitted=None, found=None, hit_p=None, hit_n=None, hit=None,
                 deferred=None):
        self.emitted = emitted
        self.found = found
        self.hit_p = hit_p
        self.hit_n = hit_n
        self.hit = hit
        self.deferred = deferred


@register
class GridUpdateIntegrator(PathIntegrator):
    """The core loop stopped at its second vertex by the grid's value there; the grid
    is attached as ``integrator.grid``."""
    plugin_name = UPDATE_PLUGIN_NAME

    grid: MomentGrid

    def init_state(self, ray: mi.Ray3f, sampler: mi.Sampler) -> Any:
        return UpdateState(mi.Spectrum(0), mi.Bool(False), dr.zeros(mi.Point3f),
                           dr.zeros(mi.Vector3f), mi.Bool(False), mi.Float(0.0))

    def after_emission(self, vertex: Vertex, state: Any) -> Any:
        first = vertex.active & (vertex.depth == 0)
        state.emitted = dr.select(first, vertex.L, state.emitted)
        state.found |= first & vertex.si.is_valid()
        return state

    def vertex_terms(self, vertex: Vertex, state: Any) -> tuple[VertexTerms | None, Any]:
        second = vertex.active & (vertex.depth == 1) & vertex.si.is_valid()
        n = vertex.si.sh_frame.n
        value = self.grid.lookup(vertex.si.p, n, vertex.sampler.next_2d(second), second)
        state.hit_p = dr.select(second, vertex.si.p, state.hit_p)
        state.hit_n = dr.select(second, n, state.hit_n)
        state.hit |= second
        # [VTT24] Sec. 4.3: the squared bias of ending at x, weighted by the squared
        # throughput y -> x (beta is f cos / p here: the path starts at y with beta 1);
        # 0 where x has no record or its record no squared-bias estimate, where a path
        # goes on instead of ending (renderers/caches/moment_grid.py, Unknown bias).
        state.deferred = dr.select(second, dr.square(mi.luminance(vertex.beta))
                                   * value.squared_bias, state.deferred)
        terms = VertexTerms(L_add=dr.select(second, value.radiance, 0.0),
                            stop=vertex.depth >= 1, stop_indirect=mi.Bool(False),
                            skip_nee=vertex.depth >= 1)
        return terms, state


def update_grid(scene: mi.Scene, integrator: GridUpdateIntegrator, seed: int,
                hit_store_probability: float, history: float | None = None) -> int:
    """One pass over the grid's representatives; returns how many vertices it updated."""
    place = integrator.grid.places()
    vertices = dr.width(place)
    if vertices:   # an opaque count: one kernel for every count
        update_places(scene, integrator, place, dr.opaque(mi.UInt32, vertices), seed,
                      hit_store_probability, history)
    return vertices


def update_places(scene: mi.Scene, integrator: GridUpdateIntegrator, place: mi.UInt32,
                  vertices: mi.UInt32, seed: int | mi.UInt32,
                  hit_store_probability: float,
                  history: mi.Float | float | None = None) -> None:
    """The pass over the representatives at the first ``vertices`` entries of ``place``
    (:meth:`MomentGrid.places`); entries past them (padding, renderers.frozen.padded) are
    masked: their paths are not traced and they update and store nothing. Lane i of
    the sampler is seeded by (seed, i) alone, so padding changes no vertex's samples.
    ``history``: the records' averaging window (:meth:`MomentGrid.accumulate`)."""
    grid = integrator.grid
    k = grid.config.samples_per_vertex
    slot, position, normal = grid.representatives(place)
    owner = dr.arange(mi.UInt32, dr.width(place) * k) // k
    p = dr.gather(mi.Point3f, position, owner)
    n = dr.gather(mi.Vector3f, normal, owner)
    offset = RECOVERY_OFFSET * dr.norm(scene.bbox().extents())
    ray = mi.Ray3f(p + offset * n, -n)
    ray.maxt = 2.0 * offset
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, dr.width(owner))
    L, _, _, state = integrator.trace(scene, sampler, ray, owner < vertices)
    # One launch of the loop for all its outputs: each reduction below would otherwise
    # re-run the whole loop kernel for its own input (docs/design.md, pitfalls).
    dr.eval(L, state, sampler)
    # A vertex the ray no longer finds (a moved or thin surface) gives no sample.
    found = dr.block_sum(dr.select(state.found, 1.0, 0.0), k) == k
    grid.accumulate(slot, L - state.emitted, found, state.deferred, history)
    store = state.hit & (sampler.next_1d() < hit_store_probability)
    hit_slot, inserted = grid.find(state.hit_p, state.hit_n, store, insert=True)
    grid.store_vertices(hit_slot, state.hit_p, state.hit_n, sampler.next_1d(), inserted)


def store_primary_vertices(scene: mi.Scene, grid: MomentGrid, sensor: mi.Sensor,
                           seed: int | mi.UInt32, probability: float) -> None:
    """The path tracer's share of exploration: each pixel's first hit kept as its cell's
    representative with ``probability`` (the paper: 1 %)."""
    film_size = sensor.film().crop_size()
    pixels = film_size.x * film_size.y
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, pixels)
    index = dr.arange(mi.UInt32, pixels)
    pixel = mi.Point2f(mi.Float(index % film_size.x), mi.Float(index // film_size.x))
    position = (pixel + sampler.next_2d()) / mi.Point2f(film_size)
    ray, _ = sensor.sample_ray(0.0, 0.5, position, mi.Point2f(0.5))
    si = scene.ray_intersect(ray)
    store = si.is_valid() & (sampler.next_1d() < probability)
    slot, inserted = grid.find(si.p, si.sh_frame.n, store, insert=True)
    grid.store_vertices(slot, si.p, si.sh_frame.n, sampler.next_1d(), inserted)
