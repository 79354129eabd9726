"""An oracle radiance cache: every query is a fresh path-traced estimate.

Tests of the caching estimators need a cache whose prediction is *right*, so
that what remains is the estimator's own bias. A converged path-traced value
of the cached quantity is such a prediction; an independent one-sample path
tracing estimate of it has the same expectation, and since every estimator in
renderers/integrators is linear in the cache's output, an estimator run with
this cache has the same expectation as with the converged oracle (its
variance is higher, which the statistical tests measure).

The cached quantities (what training.py's records target):

* ``quantity='incident'`` (NIRC, Eq. 8-9 of the NIRC paper): L_ind(x, w), the
  radiance arriving at x from direction w minus the emission of the point y it
  comes from; a ray that leaves the scene gives 0 (environment light is
  direct light).
* ``quantity='reflected'`` (NRC): L_r(x, w_o), the radiance leaving x toward
  w_o minus x's own emission, divided by NRC's albedo demodulation factor
  (nrc.py multiplies the query by it). Estimated by re-tracing the ray that
  arrived at x, from a point just off x along w_o.

The nested path is the shared PT core (path.py) run inside the caller's
symbolic loop. Its random numbers come from a PCG32 per lane seeded by a hash
of the query (position, direction) and ``seed``, so the oracle needs no access
to the caller's sampler and stays independent of it.

Interface of :class:`~renderers.caches.cache.NeuralCache` as the integrators
use it: ``surface_features(**inputs)`` then ``query(surface, direction)``. The
render integrators call it in their deferred pass after the path loop, on the
used queries only (renderers/integrators/deferred.py); the stream of a query
depends only on the query, so it is the same value as if it were evaluated in
the loop. A zero ``direction`` marks a lane whose value the caller discards
(training paths that query in the loop); no path is traced for it.

``max_depth`` bounds the nested path (segments from x); a finite bound
matches a finite ``max_depth`` of the render only at one vertex depth, so the
tests compare with unbounded paths (-1) or where the cache term is 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import drjit as dr
import mitsuba as mi

QUANTITIES = ("incident", "reflected")
#: Minimum NRC demodulation factor (renderers.integrators.cached.MIN_DEMODULATION).
MIN_DEMODULATION = 0.01


class HashedSampler:
    """The two methods of ``mi.Sampler`` the PT core calls, over a per-lane PCG32."""

    DRJIT_STRUCT = {"rng": mi.PCG32}

    def __init__(self, rng: mi.PCG32 | None = None) -> None:
        self.rng = rng

    def next_1d(self, active: mi.Bool | bool = True) -> mi.Float:
        return self.rng.next_float32(mi.Bool(active))

    def next_2d(self, active: mi.Bool | bool = True) -> mi.Point2f:
        u = self.rng.next_float32(mi.Bool(active))
        return mi.Point2f(u, self.rng.next_float32(mi.Bool(active)))


def hashed_sampler(seed: int, values: Sequence[mi.Float]) -> HashedSampler:
    """A sampler whose stream is a hash of ``seed`` and the bits of ``values``."""
    h0, h1 = mi.UInt32(seed), mi.UInt32(seed ^ 0x9E3779B9)
    for value in values:
        h0, h1 = mi.sample_tea_32(h0 ^ dr.reinterpret_array(mi.UInt32, value), h1)
    state = mi.UInt64(h0) << 32 | mi.UInt64(h1)
    return HashedSampler(mi.PCG32(1, state, mi.UInt64(h1) << 32 | mi.UInt64(h0)))


class OracleCache:
    """Path-traced stand-in for a radiance cache (module doc).

    Parameters:
        scene       the mi.Scene the integrator renders.
        quantity    'incident' (NIRC) or 'reflected' (NRC).
        max_depth   longest nested path in segments, -1 = unbounded (default).
        rr_depth    roulette start of the nested path (default 1).
        seed        mixed into every query's random stream.
    """

    def __init__(self, scene: mi.Scene, quantity: str = "incident", max_depth: int = -1,
                 rr_depth: int = 1, seed: int = 0) -> None:
        from renderers.integrators.path import PathIntegrator

        if quantity not in QUANTITIES:
            raise ValueError(f"quantity must be one of {QUANTITIES}")
        self.scene = scene
        self.quantity = quantity
        self.seed = seed
        props = mi.Properties()
        props["max_depth"] = max_depth
        props["rr_depth"] = rr_depth
        # Mitsuba's throughput roulette ends nested paths early in dim regions.
        props["rr_mode"] = "throughput"
        self.path = PathIntegrator(props)

    def surface_features(self, position: Any, normal: Any = None, roughness: Any = None,
                         albedo: Any = None, albedo_spec: Any = None) -> list[Any]:
        """[position, normal, demodulation factor]: all a query needs of the point."""
        if albedo_spec is None:
            demod = mi.Color3f(1.0)
        else:
            demod = dr.maximum(mi.Color3f(albedo) + mi.Color3f(albedo_spec), MIN_DEMODULATION)
        return [mi.Point3f(position), mi.Vector3f(normal), demod]

    def query(self, surface: Sequence[Any], direction: Any) -> mi.Color3f:
        """One path-traced estimate of the cached quantity (0 where direction is 0)."""
        position, normal, demod = surface
        d = mi.Vector3f(direction)
        active = dr.squared_norm(d) > 0
        offset = mi.math.RayEpsilon * (1.0 + dr.max(dr.abs(position)))
        if self.quantity == "incident":
            # From x along w, offset off the surface on w's side (as si.spawn_ray).
            side = dr.select(dr.dot(normal, d) >= 0, 1.0, -1.0)
            ray = mi.Ray3f(position + normal * (offset * side), d)
        else:
            # The ray that arrived at x, from a point just off x along w_o.
            ray = mi.Ray3f(position + d * (16.0 * offset), -d)
        # Queries differ by their continuous (position, direction): distinct streams.
        sampler = hashed_sampler(self.seed, [*position, *d])
        L, _, _, _ = self.path.trace(self.scene, sampler, ray, active)
        # The first hit's emission is counted unweighted by the core (a camera-like
        # first ray): subtract it exactly (y's for L_ind, x's for L_r).
        si = self.scene.ray_intersect(ray, active)
        Le = si.emitter(self.scene, active).eval(si, active)
        value = dr.select(active, (mi.Color3f(L) - Le) / demod, 0)
        return value


class ZeroCache:
    """A cache that predicts 0 everywhere: a biased estimator with it keeps only
    what the path traced itself (with max_depth 2: direct light, exactly PT's)."""

    def surface_features(self, position: Any, normal: Any = None, roughness: Any = None,
                         albedo: Any = None, albedo_spec: Any = None) -> list[Any]:
        return [mi.Point3f(position)]

    def query(self, surface: Sequence[Any], direction: Any) -> mi.Color3f:
        return dr.zeros(mi.Color3f, dr.width(surface[0]))
