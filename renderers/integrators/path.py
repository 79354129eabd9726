"""The shared path-tracing core: NEE + MIS for direct light, Russian roulette.

Every method of nirc-bench is this loop plus its own terms: `pt` is the loop
as written here; the radiance-caching methods add a cache term, a residual or
a termination decision by overriding the hooks of :class:`PathIntegrator`
(``vertex_terms``, ``after_emission``), never in a copy of the loop.

The estimator is the standard unidirectional path tracer (Veach & Guibas 1995,
"Optimally combining sampling techniques"; Mitsuba 3's ``path`` plugin): at
each vertex x_k with throughput beta_k

    L += beta_k * w_bsdf * L_e(x_k)                      (emission hit by BSDF sampling)
    L += beta_k * f(x_k) * L_e / p_light * w_light       (next-event estimation)

with the power heuristic w_a = p_a^2 / (p_a^2 + p_b^2). p_light is the pdf of
NEE's direction *including* the probability of selecting the emitter, and one
light-selection object (``renderers.integrators.lights``, pbrt-v4's
``LightSampler``) gives it in both places: NEE samples through it, and the MIS
weight of a BSDF-sampled emitter hit asks it for the pmf at the previous
vertex. The default is Mitsuba's own (uniform) selection; a method replaces it
by setting ``light_sampler_type`` (`pt-power`, `pt-spatial`). Its expectation is
the rendering equation's solution up to ``max_depth`` segments, which the
statistical test in ``tests/renderers/test_pt_agreement.py`` checks against
Mitsuba's built-in ``path``.

Russian roulette (Arvo & Kirk 1990) starts at depth ``rr_depth``:
``rr_mode='fixed'`` survives with probability ``rr_survival`` (0.9 — the
termination probability 0.1 of the NIRC paper, Sec. 6.2); ``rr_mode=
'throughput'`` uses Mitsuba's rule q = min(max(beta) * eta^2, 0.95). Both are
unbiased; they differ in path length and so in speed and variance.

A method may also weight the rest of a path: ``VertexTerms.continue_weight``
alpha scales everything after the emission the continuation ray hits (the next
segment, from the direct light at the next vertex on), so that a cache term
weighted 1 - alpha and the continuation weighted alpha blend (integrators that
set ``continuation_weights``; the variance-bounding termination of Kandlbinder
et al. 2024, Eq. 5). ``VertexTerms.segment_weight`` scales the path one step
earlier, from the vertex's own NEE on: the blend for a cache whose value already
holds the vertex's direct light (the moment grid; grid_cache.py).

A method ends a path with ``VertexTerms.stop_indirect`` (its term replaced
the indirect light at the vertex: the continuation ray is still traced, only
to collect the MIS-weighted emission it hits, so direct light stays exactly
PT's) or ``VertexTerms.stop`` (the path ends at the vertex; for a term that
already contains direct light). docs/estimators.md states each estimator.

Left out on purpose: participating media, polarisation, hidden emitters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi

from renderers.integrators import PLUGINS
from renderers.integrators.lights import LightSampler, UniformLightSampler, current_sampler

PLUGIN_NAME = "nirc_path"
RR_MODES = ("fixed", "throughput")


def mis_weight(pdf_a: mi.Float, pdf_b: mi.Float) -> mi.Float:
    """Power heuristic (beta = 2) weight of technique a; 0 where p_a is 0.

    Written as 1 / (1 + (p_b/p_a)^2): the textbook p_a^2 / (p_a^2 + p_b^2)
    overflows float32 once p_a > ~1.8e19, giving inf/inf = NaN. Such pdfs
    occur when a point on an area light samples that same light (the sampled
    direction lies in the light's plane, |cos| ~ 1e-20; docs/estimators.md,
    "Non-finite values"). As in Mitsuba's ``path``, non-finite weights become 0.
    """
    w = dr.rcp(1.0 + dr.square(pdf_b / pdf_a))
    return dr.detach(dr.select((pdf_a > 0) & dr.isfinite(w), w, 0))


@dataclass
class Vertex:
    """What the hooks see of the current path vertex (built per loop iteration)."""

    scene: mi.Scene
    sampler: mi.Sampler
    ray: mi.Ray3f                 # the ray that found this vertex
    si: mi.SurfaceInteraction3f   # the vertex
    bsdf: mi.BSDF
    beta: mi.Spectrum             # throughput up to (and including arrival at) this vertex
    L: mi.Spectrum                # radiance accumulated so far (this vertex's emission included)
    depth: mi.UInt32              # index of this vertex: 0 = first surface hit
    active: mi.Bool               # lanes whose path reached this vertex
    active_next: mi.Bool          # lanes that may extend the path beyond this vertex
    prev_bsdf_pdf: mi.Float       # pdf of the BSDF sample that led to this vertex
    prev_bsdf_delta: mi.Bool      # that sample was a delta lobe (or this is the camera ray)
    bsdf_sample: Any = None       # mi.BSDFSample3f of the continuation direction
    bsdf_weight: Any = None       # f cos / pdf of the continuation direction


@dataclass
class VertexTerms:
    """A method's contribution at a vertex (all masks per lane).

    ``L_add`` is added with the path throughput. Two ways to end a path:

    * ``stop_indirect``: the method's term replaced the *indirect* light at
      this vertex (NIRC's L_c). Direct light stays the core's: NEE here is
      MIS-weighted as usual, and the path still traces its continuation ray,
      only to collect the MIS-weighted emission it hits (no NEE there, no
      further bounce). So direct light is estimated exactly as by PT, whatever
      the method decides (the order of the NIRC authors' code).
    * ``stop``: the path ends at this vertex, its continuation is not traced
      (NRC: the cached outgoing radiance contains everything, direct light
      included, so it is combined with ``skip_nee``).

    Where ``skip_nee`` is set no NEE is done at this vertex. ``continue_weight``
    (integrators with ``continuation_weights`` only): the weight in [0, 1] of the
    path after the emission its continuation ray hits (module doc); None: 1.
    ``segment_weight``: the weight of everything from this vertex's NEE on (its direct
    light, the emission its continuation ray hits and the rest of the path), for a
    cache that holds the full reflected radiance, direct light included (the moment
    grid, grid_cache.py); None: 1.
    """

    L_add: mi.Spectrum
    stop: mi.Bool
    stop_indirect: mi.Bool
    skip_nee: mi.Bool
    continue_weight: mi.Float | None = None
    segment_weight: mi.Float | None = None


@PLUGINS.register
class PathIntegrator(mi.SamplingIntegrator):
    """Unidirectional path tracer with NEE + MIS and Russian roulette.

    Parameters (Mitsuba properties):
        max_depth    (int, default -1): longest path in segments; -1 = unbounded.
                     1 shows only directly visible emitters, 2 adds direct light.
        rr_depth     (int, default 5): first depth at which roulette may stop a path.
        rr_mode      ('fixed' | 'throughput', default 'fixed').
        rr_survival  (float, default 0.9): survival probability in 'fixed' mode.

    The AOV ``depth`` holds the number of surface vertices each path visited,
    from which the frame loop reports the average path length.

    Light selection: ``light_sampler_type`` (default :class:`UniformLightSampler`,
    Mitsuba's own selection) is built once per scene (``light_sampler(scene)``)
    and drives both NEE and the MIS weight of BSDF-sampled emitter hits; a
    method sets another class on the class or the loaded instance.

    Hooks for methods (default: nothing, so `pt` traces exactly this loop):
        ``init_state(ray, sampler)``: a PyTree of extra per-path loop state, or None.
        ``after_emission(vertex, state)``: called after a vertex's emission term.
        ``vertex_terms(vertex, state)``: after BSDF sampling, before NEE is added;
            returns (VertexTerms or None, state). NEE is MIS-weighted unless
            skipped, also at a vertex that stops.
    """

    plugin_name = PLUGIN_NAME
    #: Whether ``VertexTerms.continue_weight`` is applied (a loop variable more).
    continuation_weights = False

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.max_depth = int(props.get("max_depth", -1))
        self.rr_depth = int(props.get("rr_depth", 5))
        self.rr_mode = str(props.get("rr_mode", "fixed"))
        self.rr_survival = float(props.get("rr_survival", 0.9))
        if self.max_depth < -1 or self.max_depth == 0:
            raise ValueError("max_depth must be -1 (unbounded) or >= 1")
        if self.rr_depth < 1:
            raise ValueError("rr_depth must be >= 1")
        if self.rr_mode not in RR_MODES:
            raise ValueError(f"rr_mode must be one of {RR_MODES}")
        if not 0.0 < self.rr_survival <= 1.0:
            raise ValueError("rr_survival must be in (0, 1]")
        # Mitsuba's convention: -1 means unbounded; the loop compares unsigned.
        self.max_depth_u32 = 0xFFFFFFFF if self.max_depth == -1 else self.max_depth

    def aov_names(self) -> list[str]:
        return ["depth"]

    # ---- Light selection (one object for NEE and the MIS weight) ----

    light_sampler_type: type[LightSampler] = UniformLightSampler

    def frame_freezable(self) -> bool:
        """Whether a frame of this integrator may be frozen (renderers.frozen): the core
        reads nothing that changes between frames but the seed, unless its light
        selector reads state held in Python (``LightSampler.stateful``)."""
        return not self.light_sampler_type.stateful

    def frame_state(self, scene: mi.Scene) -> dict[str, Any]:
        """The Dr.Jit data a frame of ``scene`` reads besides the scene: the light
        selector's (its per-scene tables, built on first use on the host, which a
        recording cannot; a visibility cache's current weights). A frozen frame takes it
        as an argument and :meth:`bind_frame_state` s it."""
        return {"lights": self.light_sampler(scene).frame_arrays()}

    def bind_frame_state(self, scene: mi.Scene, state: dict[str, Any]) -> None:
        self.light_sampler(scene).bind(state["lights"])

    def light_sampler(self, scene: mi.Scene) -> LightSampler:
        """The light sampler of ``scene``, built on first use (a selector may
        precompute per-scene data, e.g. emitter powers) and kept for that scene until
        its shapes move or its emitters change (lights.current_sampler)."""
        self._light_sampler = current_sampler(getattr(self, "_light_sampler", None), scene,
                                              self.light_sampler_type)
        return self._light_sampler

    # ---- Hooks (overridden by the caching methods) ----

    def init_state(self, ray: mi.Ray3f, sampler: mi.Sampler) -> Any:
        return None

    def after_emission(self, vertex: Vertex, state: Any) -> Any:
        return state

    def vertex_terms(self, vertex: Vertex, state: Any) -> tuple[VertexTerms | None, Any]:
        return None, state

    # ---- The estimator ----

    def russian_roulette(
        self, sampler: mi.Sampler, depth: mi.UInt32, beta: mi.Spectrum, eta: mi.Float,
        active: mi.Bool,
    ) -> tuple[mi.Spectrum, mi.Bool]:
        """Return (beta / q where roulette ran, mask of paths that survive)."""
        if self.rr_mode == "fixed":
            q = mi.Float(self.rr_survival)
        else:
            q = dr.minimum(dr.max(beta) * dr.square(eta), 0.95)
        rr_active = depth >= self.rr_depth
        rr_continue = sampler.next_1d(active) < q
        beta = dr.select(rr_active, beta * dr.rcp(q), beta)
        return beta, ~rr_active | rr_continue

    def sample(
        self, scene: mi.Scene, sampler: mi.Sampler, ray: mi.RayDifferential3f,
        medium: mi.Medium = None, active: mi.Bool = True,
    ) -> tuple[mi.Spectrum, mi.Bool, list[mi.Float]]:
        L, valid_ray, depth, _ = self.trace(scene, sampler, ray, active)
        return L, valid_ray, [mi.Float(depth)]

    @dr.syntax
    def trace(
        self, scene: mi.Scene, sampler: mi.Sampler, ray: mi.Ray3f, active: mi.Bool = True,
    ) -> tuple[mi.Spectrum, mi.Bool, mi.UInt32, Any]:
        """Trace one path per lane; returns (L, valid_ray, vertex count, hook state)."""
        bsdf_ctx = mi.BSDFContext()
        lights = self.light_sampler(scene)  # emitter selection for NEE and MIS alike

        # --------------------- Loop state ---------------------
        ray = mi.Ray3f(ray)
        L = mi.Spectrum(0)                    # radiance accumulator
        beta = mi.Spectrum(1)                 # path throughput weight
        eta = mi.Float(1)                     # product of relative IORs (for roulette)
        depth = mi.UInt32(0)                  # surface vertices visited so far
        active = mi.Bool(active)              # active SIMD lanes
        valid_ray = mi.Bool(scene.environment() is not None)  # did the ray hit anything?
        prev_si = dr.zeros(mi.SurfaceInteraction3f)  # previous vertex (for the emitter pdf)
        prev_bsdf_pdf = mi.Float(1.0)         # solid-angle pdf of the last BSDF sample
        prev_bsdf_delta = mi.Bool(True)       # last BSDF sample was a delta lobe (or camera)
        last_segment = mi.Bool(False)         # the ray only collects the emission it hits
        weighted = self.continuation_weights
        pending = mi.Float(1.0)               # continue_weight of the previous vertex
        state = self.init_state(ray, sampler) # the method's own per-path state (or None)

        while dr.hint(active, max_iterations=-1, label="nirc path tracer"):
            si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All,
                                     coherent=(depth == 0), active=active)

            # ---- Direct emission (BSDF sampling hit an emitter; MIS weight vs NEE) ----
            ds = mi.DirectionSample3f(scene, si=si, ref=prev_si)
            # p_light: the pdf NEE at the previous vertex had for this direction.
            pdf_light = lights.pdf_emitter_direction(prev_si, ds, active & ~prev_bsdf_delta)
            w_bsdf = mis_weight(prev_bsdf_pdf, pdf_light)
            Le = ds.emitter.eval(si, active & (prev_bsdf_pdf > 0))
            L = dr.fma(beta, Le * w_bsdf, L)
            if weighted:   # the rest of the path, from this vertex's direct light on
                beta *= pending

            # A path whose indirect light was replaced (stop_indirect) ends here.
            active_next = ((depth + 1 < self.max_depth_u32) & si.is_valid() & active
                           & ~last_segment)
            valid_ray |= active & si.is_valid()
            bsdf = si.bsdf(ray)
            vertex = Vertex(scene, sampler, ray, si, bsdf, beta, L, depth, active, active_next,
                            prev_bsdf_pdf, prev_bsdf_delta)
            state = self.after_emission(vertex, state)

            # ---- Emitter sampling (next-event estimation; MIS weight vs BSDF) ----
            active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            ds_em, em_weight = lights.sample_emitter_direction(
                si, sampler.next_2d(active_em), active_em)
            active_em &= ds_em.pdf != 0
            wo_em = si.to_local(ds_em.d)

            # ---- BSDF evaluation at the light direction and BSDF sampling ----
            u1 = sampler.next_1d(active_next)
            u2 = sampler.next_2d(active_next)
            bsdf_val, bsdf_pdf, bsdf_sample, bsdf_weight = bsdf.eval_pdf_sample(
                bsdf_ctx, si, wo_em, u1, u2, active_next)
            w_light = dr.select(ds_em.delta, 1.0, mis_weight(ds_em.pdf, bsdf_pdf))

            # ---- The method's terms at this vertex (cache term, residual, termination) ----
            vertex.bsdf_sample, vertex.bsdf_weight = bsdf_sample, bsdf_weight
            terms, state = self.vertex_terms(vertex, state)
            if terms is not None:
                active_em &= ~terms.skip_nee
                L = dr.fma(beta, terms.L_add, L)
                active_next &= ~terms.stop
                last_segment = active_next & terms.stop_indirect
                if weighted:
                    pending = (mi.Float(1.0) if terms.continue_weight is None
                               else mi.Float(terms.continue_weight))
                if terms.segment_weight is not None:
                    # The rest of the path from this vertex's direct light on.
                    beta *= terms.segment_weight

            L[active_em] = dr.fma(beta, bsdf_val * em_weight * w_light, L)

            # ---- Update loop variables (continue along the BSDF sample) ----
            ray = si.spawn_ray(si.to_world(bsdf_sample.wo))
            beta *= bsdf_weight
            eta *= bsdf_sample.eta
            prev_si = dr.detach(si, True)
            prev_bsdf_pdf = bsdf_sample.pdf
            prev_bsdf_delta = mi.has_flag(bsdf_sample.sampled_type, mi.BSDFFlags.Delta)
            depth[si.is_valid() & active] += 1

            # ---- Stopping criterion (Russian roulette; zero throughput) ----
            beta, survive = self.russian_roulette(sampler, depth, beta, eta, active_next)
            active = active_next & survive & (dr.max(beta) != 0)

        return L, valid_ray, depth, state


def register(name: str = PLUGIN_NAME, cls: type = PathIntegrator) -> None:
    """Register an integrator class with Mitsuba for the current variant (idempotent;
    renderers.integrators.register_plugins registers every plugin this way)."""
    mi.register_integrator(name, lambda props: cls(props))
