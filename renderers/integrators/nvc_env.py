"""Direct environment light through a neural visibility cache (`nvc-env`).

NIRC paper, Sec. 5 (Fig. 11): a cache V_c(x, w) in [0, 1] predicts whether a
ray from x toward w escapes to the environment map (NIRC's position and
direction encodings, one sigmoid output), trained online on shadow-ray
outcomes. It replaces the shadow rays of the environment's next-event
estimation at every shading vertex of the PT core (path.py); other emitters
and indirect light stay the core's.

The environment's NEE term at a vertex x is, with the core's MIS weights
(power heuristic, path.py) kept for BSDF-sampled hits of the environment,

    I_env(x) = ∫ L_env(w) f(x, w) cos V(x, w) w_L(w) dw,
    w_L(w) = p_L^2 / (p_L^2 + p_f^2),  p_L = p(env | x) p_env(w),  p_f = the BSDF pdf

(p(env | x) the light selector's pmf of the environment: what the core's
weight of a BSDF-sampled environment hit uses, so w_L + w_bsdf = 1 for every
direction). Directions are drawn from the environment's importance sampling
p_env (``emitter.sample_direction``), never from the BSDF. Writing
g(w) = L_env f cos w_L / p_env:

* cache level (NIRC Eq. 12 with V L_env in place of the cached radiance):
  I_c = 1/N_c sum_i g(w_i) V_c(x, w_i), w_i ~ p_env — no shadow rays;
* unbiased (two-level MC, NIRC Eq. 10-12): I_c + g(w) (V(x, w) - V_c(x, w))
  along one independent w ~ p_env, V from one shadow ray: expectation
  I_env(x) for any cache;
* biased (``estimator='biased'``, NIRC Eq. 13): I_c alone; exact where V_c = V.

The core must not estimate I_env as well: its selector is wrapped
(:class:`WithoutEnvironmentNEE`) so that NEE samples that picked the
environment contribute 0 (their expectation is exactly I_env), while the pdf
it reports for the MIS weight of BSDF-sampled hits stays p_L. Where the
environment is the only emitter the core's NEE is skipped altogether
(``skip_nee``), saving its shadow ray.

The cache is evaluated after the path loop, on the used queries only
(deferred.py, through :class:`CachedPathIntegrator`): at a vertex the loop
records the ray that found it (the deferred pass re-creates the vertex for
its position) and, per query, the direction and the factor that
multiplies V_c in the estimate (g / N_c for the cache level, -g for the
residual); the residual's g V is added in the loop. Every NEE vertex is a
cache vertex, so the p_env directions stay drawn in the loop (unlike NIRC's
N_c directions: no lane that does NEE could skip them), and a path has up to
max_depth - 1 of them (the buffer's bound);
with unbounded depth the buffer starts with one vertex slot per lane and a
frame that needed more is traced again with the same random numbers
(cached.py), keeping the count for later frames.

Training data (:func:`visibility_records`; frozen, :class:`EnvVisibilityRecords`):
every frame, first hits of camera rays through random film positions and the
vertex one cosine-sampled bounce further (where GI paths shade), each with one
direction drawn as the estimator draws it (p_env); the target is 1 if the shadow
ray escapes.
"""

from __future__ import annotations

from typing import Any, Protocol

import drjit as dr
import mitsuba as mi

from renderers.caches import TrainingRecords
from renderers.frozen import FrozenRecords
from renderers.integrators import register
from renderers.integrators.cached import CachedPathIntegrator, CacheState, cache_inputs
from renderers.integrators.deferred import QueryLayout
from renderers.integrators.lights import UniformLightSampler
from renderers.integrators.path import Vertex, VertexTerms, mis_weight
from renderers.seeding import derive_seed

NVC_ENV_PLUGIN = "nirc_nvc_env"


class NVCEnvSettings(Protocol):
    """What the estimator reads of the `nvc-env` method's validated parameters."""

    estimator: str
    nc: int
    target: str


def environment(scene: mi.Scene) -> mi.EmitterPtr:
    """The scene's environment emitter as a pointer of width 1, gathered from the
    scene's emitter array (an input of a frozen frame, renderers.frozen). Calling the
    emitter object itself inside a frozen recording aborted Dr.Jit 1.5's CUDA backend
    ("jit_var(r0): unknown variable!"; docs/timing.md, "Frozen frames"); through the
    pointer it is a virtual call of one instance, bit-equal on the CPU."""
    target = scene.environment()
    index = next(i for i, e in enumerate(scene.emitters()) if e is target)
    return dr.gather(mi.EmitterPtr, scene.emitters_dr(), mi.UInt32(index))


def is_environment(scene: mi.Scene, emitter: mi.EmitterPtr) -> mi.Bool:
    """Lanes whose ``emitter`` is the scene's environment emitter."""
    return (dr.reinterpret_array(mi.UInt32, emitter)
            == dr.reinterpret_array(mi.UInt32, environment(scene)))


class WithoutEnvironmentNEE(UniformLightSampler):
    """Mitsuba's selection, with NEE samples that picked the environment set to 0;
    ``pdf_emitter_direction`` (the MIS weight of BSDF-sampled hits) is unchanged."""

    def sample_emitter_direction(self, si, u, active):
        ds, weight = super().sample_emitter_direction(si, u, active)
        env = is_environment(self.scene, ds.emitter)
        ds.pdf[env] = 0
        weight[env] = 0
        return ds, weight


class OneOutput:
    """A one-output (visibility) cache seen as the deferred pass expects a cache: its
    ``query`` returns a Spectrum (the value on every channel), not a list."""

    def __init__(self, cache: Any) -> None:
        self.cache = cache

    def surface_features(self, position: mi.Point3f, normal: mi.Vector3f | None = None,
                         **_: Any) -> list[mi.Float]:
        return self.cache.surface_features(position, normal)

    def query(self, surface: list[mi.Float], direction: mi.Vector3f) -> mi.Spectrum:
        return mi.Spectrum(self.cache.query(surface, direction)[0])

    def __getattr__(self, name: str) -> Any:
        """Everything else is the wrapped cache's (its inference state, for frozen passes)."""
        return getattr(self.cache, name)


def surface_inputs(si: mi.SurfaceInteraction3f) -> dict[str, Any]:
    """A vertex's inputs as the query buffer stores them: the visibility cache reads
    the position (and a test oracle the normal); roughness and albedo are unused."""
    return {"position": si.p, "normal": si.n, "roughness": mi.Float(0),
            "albedo": mi.Color3f(0)}


class EnvVisibility:
    """The environment's NEE as the two-level estimator of the module docstring: one
    query channel (deferred.QueryChannel) of a :class:`CachedPathIntegrator`.

    ``target='visibility'``: the cache predicts V(x, w) and a query's factor is
    g(w) = L_env f cos w_L / p_env. ``target='radiance'`` (NIRC predicting the
    same direct light, the NIRC paper's Fig. 11): the cache predicts the RGB
    incident radiance L_env(w) V(x, w) from NIRC's inputs, and a query's factor
    is h(w) = f cos w_L / p_env (g = L_env h). Vertices are counted by the
    ``counter`` field of ``CacheState``; a path has at most max_depth - 1 of them.
    """

    drawn_slots = 0   # its directions are drawn in the loop (module docstring)

    def __init__(self, params: NVCEnvSettings, cache: Any, max_depth: int,
                 counter: str = "cache_vertices") -> None:
        self.estimator, self.nc, self.target = params.estimator, params.nc, params.target
        self.cache = OneOutput(cache) if self.target == "visibility" else cache
        self.max_depth, self.counter = max_depth, counter
        self.vertex_slots = 1
        self.queries: Any = None   # the frame's buffer (CachedPathIntegrator.sample)

    def query_layout(self) -> QueryLayout:
        """N_c queries per NEE vertex, + 1 (the residual's) when unbiased; a path has at
        most max_depth - 1 NEE vertices (exact), else as many as seen so far."""
        vertices = self.max_depth - 1 if self.max_depth > 0 else self.vertex_slots
        return QueryLayout(vertices, self.nc + (self.estimator == "unbiased"))

    def surface_inputs(self, si: mi.SurfaceInteraction3f, bsdf: mi.BSDF) -> dict[str, Any]:
        return surface_inputs(si) if self.target == "visibility" else cache_inputs(si, bsdf)

    def drawn_query(self, si, bsdf, rng, slot, count):
        raise NotImplementedError("the environment's queries are drawn in the loop")

    def env_sample(self, vertex: Vertex, lights: Any, active: mi.Bool
                   ) -> tuple[mi.DirectionSample3f, mi.Spectrum, mi.Spectrum]:
        """One w ~ p_env, g(w) = L_env f cos w_L / p_env and the factor of the cache's
        value in the estimate (g, or h = g / L_env for a radiance cache); 0 where p_env
        or f is 0. ``lights``: the integrator's selector, whose pdf w_L uses."""
        si, scene = vertex.si, vertex.scene
        ds, env_weight = environment(scene).sample_direction(
            si, vertex.sampler.next_2d(active), active)
        active &= ds.pdf > 0
        f, pdf_f = vertex.bsdf.eval_pdf(mi.BSDFContext(), si, si.to_local(ds.d), active)
        w_light = mis_weight(lights.pdf_emitter_direction(si, ds, active), pdf_f)
        g = env_weight * f * w_light   # env_weight = L_env / p_env
        factor = g if self.target == "visibility" else f * w_light / ds.pdf
        return ds, dr.select(active, g, 0), dr.select(active, factor, 0)

    def terms(self, vertex: Vertex, state: CacheState, lights: Any) -> mi.Spectrum:
        """The vertex's estimate of I_env (added now; cache values after the loop); counts
        the vertex in ``state``."""
        # Where the core does NEE (path.py): a smooth BSDF at a vertex that may extend.
        active = vertex.active_next & mi.has_flag(vertex.bsdf.flags(), mi.BSDFFlags.Smooth)
        counted = getattr(state, self.counter)
        handle = self.queries.vertex(counted, vertex, active)
        # ---- Cache level: I_c = 1/N_c sum_i g(w_i) V_c(x, w_i) (NIRC Eq. 12) ----
        L_add = mi.Spectrum(0)
        for slot in range(self.nc):
            ds, _, factor = self.env_sample(vertex, lights, active)
            L_add += self.queries.add(handle, slot, ds.d, factor / self.nc, active)
        # ---- Residual: g(w) (V(x, w) - V_c(x, w)), one shadow ray (NIRC Eq. 11) ----
        if self.estimator == "unbiased":
            ds, g, factor = self.env_sample(vertex, lights, active)
            use = active & (dr.max(g) != 0)
            visible = use & ~vertex.scene.ray_test(vertex.si.spawn_ray_to(ds.p), use)
            L_add += dr.select(visible, g, 0)
            L_add += self.queries.add(handle, self.nc, ds.d, -factor, use)
        setattr(state, self.counter, dr.select(active, counted + 1, counted))
        return dr.select(active, L_add, 0)


def only_environment(scene: mi.Scene) -> mi.Bool:
    """Where the environment is the only emitter the core's NEE has nothing left to do."""
    return mi.Bool(len(scene.emitters()) == 1)


@register
class NVCEnvIntegrator(CachedPathIntegrator):
    """PT core whose environment NEE is the two-level estimator of the module docstring."""
    plugin_name = NVC_ENV_PLUGIN

    light_sampler_type = WithoutEnvironmentNEE

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.env: EnvVisibility | None = None   # set by configure

    def configure(self, params: NVCEnvSettings, cache: Any) -> None:
        """Take the method's parameters (validated by its model) and the visibility cache."""
        self.env = EnvVisibility(params, cache, self.max_depth)

    def query_channels(self) -> list[Any]:
        if self.env is None:
            raise RuntimeError("the nvc-env integrator needs configure(params, cache) before "
                               "it renders (renderers.methods.nvc_env.build does it)")
        return [self.env]

    def vertex_terms(self, vertex: Vertex, state: CacheState) -> tuple[VertexTerms, CacheState]:
        L_add = self.env.terms(vertex, state, self.light_sampler(vertex.scene))
        terms = VertexTerms(L_add=L_add, stop=mi.Bool(False), stop_indirect=mi.Bool(False),
                            skip_nee=only_environment(vertex.scene))
        return terms, state


def visibility_records(scene: mi.Scene, points: int, seed: int,
                       target: str = "visibility") -> TrainingRecords:
    """One frame of training data (module docstring): ``points`` camera first hits and as
    many second vertices, each with one p_env direction and its 0/1 shadow-ray outcome
    (``target='radiance'``: L_env(w) times that outcome, RGB, with NIRC's inputs)."""
    return EnvVisibilityRecords(points, target, frozen=False)(scene, seed)


class EnvVisibilityRecords(FrozenRecords):
    """:func:`visibility_records` of a cache's settings, frozen (renderers.frozen) where
    freezing is on: the two seeds are the recording's arguments."""

    def __init__(self, points: int, target: str = "visibility",
                 frozen: bool | None = None) -> None:
        self.points, self.target = points, target
        super().__init__(frozen)

    def arguments(self, seed: int) -> tuple[Any, ...]:
        return (dr.opaque(mi.UInt32, seed),
                dr.opaque(mi.UInt32, derive_seed(seed, "shadow rays")))

    def records(self, scene: mi.Scene, seed: mi.UInt32,
                shadow_seed: mi.UInt32) -> TrainingRecords:
        points = self.points
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed, points)
        ray, _ = scene.sensors()[0].sample_ray(time=0.0, sample1=sampler.next_1d(),
                                               sample2=sampler.next_2d(),
                                               sample3=sampler.next_2d())
        first = scene.ray_intersect(ray)
        bounce = mi.warp.square_to_cosine_hemisphere(sampler.next_2d())
        second = scene.ray_intersect(first.spawn_ray(first.to_world(bounce)), first.is_valid())

        # Lanes 0 .. points - 1: the first hits; points .. 2 points - 1: the second vertices.
        index = dr.arange(mi.UInt32, 2 * points) % points
        is_first = dr.arange(mi.UInt32, 2 * points) < points

        def both(a: Any, b: Any) -> Any:
            return dr.select(is_first, dr.gather(type(a), a, index),
                             dr.gather(type(b), b, index))

        si = dr.zeros(mi.SurfaceInteraction3f, 2 * points)
        si.p, si.n = both(first.p, second.p), both(first.n, second.n)  # what the rays read
        valid = both(first.is_valid(), second.is_valid())

        sampler.seed(shadow_seed, 2 * points)
        ds, env_weight = environment(scene).sample_direction(si, sampler.next_2d(), valid)
        escapes = valid & (ds.pdf > 0) & ~scene.ray_test(si.spawn_ray_to(ds.p), valid)
        if self.target == "visibility":
            records = TrainingRecords(position=si.p, target=[dr.select(escapes, 1.0, 0.0)],
                                      direction=ds.d, valid=valid)
        else:
            radiance = dr.select(escapes, env_weight * ds.pdf, 0.0)   # L_env(w) V(x, w)
            inputs = both_inputs(first, second, both)
            records = TrainingRecords(target=[radiance[0], radiance[1], radiance[2]],
                                      direction=ds.d, valid=valid, **inputs)
        dr.eval(records.position, records.target, records.direction, records.valid)
        return records


def both_inputs(first: mi.SurfaceInteraction3f, second: mi.SurfaceInteraction3f,
                both: Any) -> dict[str, Any]:
    """NIRC's cache inputs (cached.cache_inputs) of the first hits and second vertices,
    in the lanes ``both`` lays them out in."""
    inputs = [cache_inputs(si, si.bsdf()) for si in (first, second)]
    return {name: both(inputs[0][name], inputs[1][name]) for name in inputs[0]}


# ---- Registration (per Mitsuba variant: the `nvc-env` method calls it when a render starts) ----
