"""The render pass of the `grid-cache` method: the path-tracing core terminating into
the hashed-grid moment cache where a variance-trading policy says so ([VTT24]
Sec. 4 and 5; docs/variance_trading.md).

The grid (renderers/caches/moment_grid.py) holds at every record the *full* reflected
radiance L_r of its diffuse points, direct light included (the update pass,
grid_update.py). So at a vertex x_d the policy (renderers/integrators/termination,
the kinds that serve 'grid') answers a continuation weight alpha, and

* alpha = 1: the path goes on as PT;
* alpha = 0: the path ends with beta rc(x_d) and does no NEE at x_d (rc holds it);
* 0 < alpha < 1 (var-bound's blend, Eq. 5): beta (1 - alpha) rc(x_d) is added, and
  the one more segment is weighted alpha *from x_d's NEE on* — x_d's direct light,
  the emission the continuation ray hits at x_{d+1} and the cache there, where the
  path then ends without NEE (``VertexTerms.segment_weight``):

      beta [(1 - alpha) rc(x_d) + alpha (NEE(x_d) + (f cos / p)(Le(x_{d+1}) w + rc(x_{d+1})))]

  which is the discrete model's blend (renderers/termination_model.py, ``blend``)
  with the next vertex's emission standing for its direct light. Where x_{d+1} has no
  record the path goes on as PT (already weighted alpha): unbiased, only longer.

A vertex may use the cache (``usable``) where its record exists (it has been updated
at least once), its BSDF has a smooth lobe and the path may go on (``max_depth``).
The weights of the blend are :attr:`GridCacheIntegrator.blend` (cache here, segment,
cache at the next vertex) = (1 - alpha, alpha, 1), a seam the tests plant wrong blends
into.

AOVs: ``depth`` (surface vertices visited, as every integrator), ``cache_depth`` (1 +
index of the first vertex that used the cache; 0: none), ``cache_vertices`` and
``weighted_length``: the paper's path length (Sec. 6, Table 1) — the vertices up to
the termination vertex, the blended segment counted by its weight alpha (a path that
ends in the cache at its first hit: 1; one blended there: 1 + alpha); a path that never
used the cache counts the vertices it visited, as ``depth``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import drjit as dr
import mitsuba as mi

from renderers.caches.moment_grid import GridValue, MomentGrid
from renderers.integrators import register
from renderers.integrators.cached import CacheState, new_cache_state, update_spread
from renderers.integrators.path import PathIntegrator, Vertex, VertexTerms
from renderers.integrators.termination import TerminationPolicy, TerminationQuery

PLUGIN_NAME = "nirc_grid_cache"

#: (alpha) -> the weights of (the cache at this vertex, the segment from this vertex's
#: NEE on, the cache at the vertex that ends a blended path).
Blend = Callable[[Any], tuple[Any, Any, Any]]


def eq5_blend(alpha: Any) -> tuple[Any, Any, Any]:
    """Eq. 5's blend: the cache weighted 1 - alpha, the one more segment alpha (its
    direct light and the cache at its end alike)."""
    return 1.0 - alpha, alpha, 1.0


class GridState(CacheState):
    """The caching estimators' per-path state (cached.py) and what the grid adds."""

    DRJIT_STRUCT = {
        **CacheState.DRJIT_STRUCT,
        "policy_state": dict,            # the policy's own (TerminationPolicy.path_state)
        "pending": mi.Bool,              # blended at the previous vertex: ends at this one
        "next_cache_weight": mi.Float,   # weight of the cache where a blended path ends
        "length": mi.Float,              # the paper's path length, once the cache was used
    }

    def __init__(self, policy_state=None, pending=None, next_cache_weight=None,
                 length=None, **fields):
        super().__init__(**fields)
        self.policy_state = policy_state
        self.pending = pending
        self.next_cache_weight = next_cache_weight
        self.length = length


class GridStatistics:
    """What a policy's :meth:`TerminationQuery.statistics` reads: the record looked up
    at the current vertex (once, also for the cache term)."""

    def __init__(self, value: GridValue) -> None:
        self.value = value

    def statistics(self, si: mi.SurfaceInteraction3f, active: mi.Bool) -> GridValue:
        return self.value


@register
class GridCacheIntegrator(PathIntegrator):
    """The PT core asking ``policy`` at every vertex and terminating into ``grid``
    (module doc); both are attached after loading (``integrator.grid = ...``,
    ``integrator.policy = ...``). Properties: the core's (max_depth, rr_*)."""
    plugin_name = PLUGIN_NAME

    grid: MomentGrid
    policy: TerminationPolicy
    blend: Blend = staticmethod(eq5_blend)

    def aov_names(self) -> list[str]:
        return ["depth", "cache_depth", "cache_vertices", "weighted_length"]

    def frame_state(self, scene: mi.Scene) -> dict[str, Any]:
        """The core's, and the arrays the grid's lookups read (the propagation pass changes
        them every frame)."""
        return {**super().frame_state(scene), "grid": self.grid.lookup_arrays()}

    def bind_frame_state(self, scene: mi.Scene, state: dict[str, Any]) -> None:
        super().bind_frame_state(scene, state)
        self.grid.bind_lookup(state["grid"])

    def init_state(self, ray: mi.Ray3f, sampler: mi.Sampler) -> GridState:
        base = new_cache_state()
        fields = {name: getattr(base, name) for name in CacheState.DRJIT_STRUCT}
        return GridState(self.policy.path_state(), mi.Bool(False), mi.Float(1.0), mi.Float(0.0),
                         **fields)

    def after_emission(self, vertex: Vertex, state: GridState) -> GridState:
        return update_spread(vertex, state)    # the spread, for area-spread

    def vertex_terms(self, vertex: Vertex, state: GridState) -> tuple[VertexTerms, GridState]:
        si = vertex.si
        valid = vertex.active & si.is_valid()
        value = self.grid.lookup(si.p, si.sh_frame.n, vertex.sampler.next_2d(valid), valid)
        smooth = mi.has_flag(vertex.bsdf.flags(), mi.BSDFFlags.Smooth)
        usable = vertex.active_next & value.found & smooth

        # ---- The policy's continuation weight ([VTT24] Sec. 4.2-4.3) ----
        query = TerminationQuery(vertex, state, usable,
                                 cache=GridStatistics(value))
        alpha, state = self.policy.continuation(query)
        alpha = dr.select(usable, mi.Float(alpha), 1.0)
        ending = usable & state.pending          # the vertex a blended path ends at
        alpha = dr.select(ending, 0.0, alpha)

        # ---- Cache term and the blend (Eq. 5) ----
        cache_weight, segment_weight, next_cache_weight = self.blend(alpha)
        uses = usable & (alpha < 1.0)
        stop = uses & (alpha <= 0.0)
        blends = uses & (alpha > 0.0)
        weight_here = dr.select(ending, state.next_cache_weight, cache_weight)
        L_add = dr.select(uses, weight_here * value.radiance, 0.0)

        # ---- Path statistics: where the cache was first used, the paper's length ----
        index = mi.Float(vertex.depth + 1)
        first_use = uses & (state.cache_depth == 0)
        state.length = dr.select(first_use, index + dr.select(blends, alpha, 0.0),
                                 state.length)
        state.cache_depth = dr.select(first_use, vertex.depth + 1, state.cache_depth)
        state.cache_vertices = dr.select(uses, state.cache_vertices + 1, state.cache_vertices)
        state.next_cache_weight = dr.select(blends, mi.Float(next_cache_weight), 1.0)
        state.pending = blends
        terms = VertexTerms(L_add=L_add, stop=stop, stop_indirect=mi.Bool(False),
                            skip_nee=stop,
                            segment_weight=dr.select(blends, mi.Float(segment_weight), 1.0))
        return terms, state

    def sample(self, scene, sampler, ray, medium=None, active=True):
        L, valid_ray, depth, state = self.trace(scene, sampler, ray, active)
        length = dr.select(state.cache_depth > 0, state.length, mi.Float(depth))
        return L, valid_ray, [mi.Float(depth), mi.Float(state.cache_depth),
                              mi.Float(state.cache_vertices), length]


