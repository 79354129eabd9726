"""Light selection: which emitter a shading point samples, as one object.

As pbrt-v4's ``LightSampler`` (``src/pbrt/lightsamplers.h``; PBR 4th ed.,
Sec. 12.6), one object answers both questions the path-tracing core asks
about emitters, so that next-event estimation and the MIS weight of
BSDF-sampled emitter hits cannot disagree:

* ``sample_emitter_direction(si, u)`` (NEE): pick emitter i with probability
  p(i | x), sample a direction on it with ``emitter.sample_direction``; the
  weight is that emitter's radiance / pdf divided by p(i | x), the pdf is
  p(i | x) * emitter.pdf_direction.
* ``pdf_emitter_direction(prev_si, ds)`` (MIS of a BSDF sample that hit
  emitter i from the previous vertex x'): p(i | x') * emitter.pdf_direction,
  i.e. the pdf NEE *at that previous vertex* would have had for the same
  direction — the p_light of Veach's balance/power heuristic (Veach 1997,
  Sec. 9.2).

A selector only provides ``sample(si, u) -> (index, pmf, u_reused)`` and
``pmf(si, index)``; the direction sampling and pdf above are built on them
once, here. The estimator is unbiased for any selector whose pmf is positive
for every emitter that can contribute at x and that returns the same pmf in
``sample`` and ``pmf``.

A selector whose NEE pick has no tractable pmf (resampled importance sampling,
the clustered visibility cache of ``renderers.integrators.nvc_lights``)
overrides ``select(si, u) -> (index, weight, pmf, u_reused)`` instead: NEE
weights the emitter sample by ``weight``, an unbiased contribution weight of
the pick (E[g(i) weight] = sum of g over the emitters it can pick), and the MIS
weights of both strategies use ``pmf`` (= ``pmf(si, index)``). The balance
heuristic stays a partition of unity whatever that pmf is, so NEE plus the
BSDF-sampled hits stay unbiased as long as ``pmf`` is 0 wherever the pick
cannot land on a contributing emitter (there the BSDF sample must take the whole
weight; Veach 1997, Sec. 9.2: MIS weights need only sum to one). The
default ``select`` is ``sample`` with weight = 1 / pmf.

``sampler_at(si)`` returns a draw function of ``u`` at one point (``sample``
without recomputing per-point weights for every draw): the candidate source of
ReSTIR (``renderers.integrators.restir``).

Selectors:

* :class:`UniformLightSampler` (the core's default): Mitsuba's own
  ``Scene::sample_emitter_direction`` / ``pdf_emitter_direction``, called
  directly (uniform selection, or the emitters' ``sampling_weight``), so
  `pt` stays Mitsuba's ``path`` estimator and as fast.
* :class:`PowerLightSampler`: p(i) ∝ Φ_i, the approximate emitted power
  (pbrt-v4's ``PowerLightSampler``), the same at every point.
* :class:`SpatialLightSampler`: p(i | x) ∝ Φ_i / max(|x - c_i|^2, r_i^2),
  with c_i and r_i the centre and half diagonal of the emitter's bounding
  box — the distance part of pbrt-v4's ``BVHLightSampler`` importance, without
  the tree and the orientation bounds (cost O(number of emitters) per query).
* :class:`WeightedLightSampler`: the base of selectors with per-point
  weights, p(i | x) = w_i(x) / sum_j w_j(x); the spatial selector above and
  the neural-visibility selector of `nvc-lights`
  (``renderers.integrators.nvc_lights``) define only ``weights``.

Power Φ_i (computed once per scene, :func:`emitter_powers`): an area emitter
π · A · mean luminance of its radiance over POWER_SAMPLES points of its shape;
an environment emitter 4π² · R² · mean luminance over POWER_SAMPLES directions
(R: the scene's bounding-sphere radius; pbrt-v4's ``UniformInfiniteLight::
Phi``). Emitters whose radiance cannot be evaluated this way (point, spot,
directional lights: delta emitters) get the mean power of the others. Every
power is floored at POWER_FLOOR times the mean, so no emitter has pmf 0.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

POWER_SAMPLES = 256      # points (directions) per emitter for its mean radiance
POWER_FLOOR = 1e-3       # relative to the mean power: every emitter stays selectable


class LightSampler:
    """Base of the light selectors: NEE and the MIS light pdf built on ``sample``/``pmf``.

    Subclasses implement ``sample`` and ``pmf``; both receive the shading
    point, so a selector may depend on it (``pmf`` of a BSDF-sampled hit is
    evaluated at the previous vertex, where NEE would have sampled).
    """

    #: Its selection reads Dr.Jit values held in Python that change between frames and
    #: that :meth:`frame_arrays` does not hand over: a frame that uses it is not frozen
    #: (renderers.frozen), since a replay would not see the new values.
    stateful = False
    #: The scene's generation it was built for (:func:`current_sampler`).
    generation: tuple[int, str] | None = None
    #: The attributes holding the per-scene Dr.Jit data the selection reads: a frozen
    #: frame takes them as arguments (:meth:`frame_arrays`, :meth:`bind`), since a
    #: recording may only read Dr.Jit values it was given.
    ARRAYS: tuple[str, ...] = ("index_table",)

    def frame_arrays(self) -> dict[str, Any]:
        """The Dr.Jit data the selection reads now (a PyTree): :data:`ARRAYS`."""
        return {name: getattr(self, name) for name in self.ARRAYS}

    def bind(self, arrays: dict[str, Any]) -> None:
        """Read the data of :meth:`frame_arrays` from ``arrays`` (a frozen frame's
        arguments)."""
        for name in self.ARRAYS:
            setattr(self, name, arrays[name])

    def __init__(self, scene: mi.Scene) -> None:
        self.scene = scene
        self.emitters = scene.emitters()
        self.count = len(self.emitters)
        # Emitter pointers are registry ids in the JIT variants: a table from
        # id to position in scene.emitters() turns ds.emitter into an index.
        ids = dr.reinterpret_array(mi.UInt32, scene.emitters_dr()).numpy() if self.count else []
        table = np.zeros(int(max(ids, default=0)) + 1, dtype=np.uint32)
        table[np.asarray(ids, dtype=np.int64)] = np.arange(self.count, dtype=np.uint32)
        self.index_table = mi.UInt32(table)

    # ---- What a selector defines ----

    def sample(self, si: mi.SurfaceInteraction3f, u: mi.Float,
               active: mi.Bool) -> tuple[mi.UInt32, mi.Float, mi.Float]:
        """Pick an emitter for the point ``si``: (index, its pmf, ``u`` rescaled to [0, 1))."""
        raise NotImplementedError

    def pmf(self, si: mi.SurfaceInteraction3f, index: mi.UInt32, active: mi.Bool) -> mi.Float:
        """The probability that ``sample`` at ``si`` picks emitter ``index``."""
        raise NotImplementedError

    def select(self, si: mi.SurfaceInteraction3f, u: mi.Point2f, active: mi.Bool
               ) -> tuple[mi.UInt32, mi.Float, mi.Float, mi.Point2f]:
        """NEE's pick: (index, contribution weight, MIS pmf, ``u`` for the emitter's sample)."""
        index, pmf, u_x = self.sample(si, u.x, active)
        return index, dr.select(pmf > 0, dr.rcp(pmf), 0), pmf, mi.Point2f(u_x, u.y)

    def sampler_at(self, si: mi.SurfaceInteraction3f, active: mi.Bool
                   ) -> Callable[[mi.Float], tuple[mi.UInt32, mi.Float, mi.Float]]:
        """``u -> sample(si, u, active)`` for repeated draws at the same points."""
        return lambda u: self.sample(si, u, active)

    # ---- Built on it: NEE and the MIS light pdf ----

    def index_of(self, emitter: mi.EmitterPtr, active: mi.Bool) -> mi.UInt32:
        """Position of ``emitter`` in ``scene.emitters()`` (0 for a null pointer)."""
        ids = dr.reinterpret_array(mi.UInt32, emitter)
        return dr.gather(mi.UInt32, self.index_table, ids, active & (ids != 0))

    def sample_emitter_direction(self, si: mi.SurfaceInteraction3f, u: mi.Point2f,
                                 active: mi.Bool) -> tuple[mi.DirectionSample3f, mi.Spectrum]:
        """NEE: (direction sample with pdf = pmf * emitter pdf, Le / pdf, 0 if occluded)."""
        if self.count == 0:
            return dr.zeros(mi.DirectionSample3f), mi.Spectrum(0)
        index, selection_weight, pmf, u = self.select(si, u, active)
        emitter = dr.gather(mi.EmitterPtr, self.scene.emitters_dr(), index, active)
        ds, weight = emitter.sample_direction(si, u, active)
        active &= (ds.pdf != 0) & (pmf > 0)
        ds.pdf *= pmf
        weight = dr.select(active, weight * selection_weight, 0)
        # Visibility as Scene::sample_emitter_direction: an occluded sample has pdf 0.
        occluded = self.scene.ray_test(si.spawn_ray_to(ds.p), active)
        weight[occluded] = 0
        ds.pdf[occluded | ~active] = 0
        return ds, weight

    def pdf_emitter_direction(self, prev_si: mi.SurfaceInteraction3f, ds: mi.DirectionSample3f,
                              active: mi.Bool) -> mi.Float:
        """p_light of a BSDF sample from ``prev_si`` that hit ``ds.emitter``."""
        if self.count == 0:     # nothing to hit (and no selection to evaluate)
            return mi.Float(0)
        active &= dr.reinterpret_array(mi.UInt32, ds.emitter) != 0  # an emitter was hit
        pmf = self.pmf(prev_si, self.index_of(ds.emitter, active), active)
        return dr.select(active, pmf * ds.emitter.pdf_direction(prev_si, ds, active), 0)


class UniformLightSampler(LightSampler):
    """Mitsuba's selection (uniform, or by ``sampling_weight``): the core's default.

    NEE and the MIS pdf call the scene's own routines, so the default path
    tracer is exactly Mitsuba's ``path`` and pays nothing for the hook.
    """

    ARRAYS = ()

    def __init__(self, scene: mi.Scene) -> None:
        # No index table: the scene's routines need none (and building it evaluates).
        self.scene = scene

    def sample(self, si, u, active):
        index, weight, u_x = self.scene.sample_emitter(u, active)
        return index, dr.rcp(weight), u_x

    def pmf(self, si, index, active):
        return self.scene.pdf_emitter(index, active)

    def sample_emitter_direction(self, si, u, active):
        return self.scene.sample_emitter_direction(si, u, True, active)

    def pdf_emitter_direction(self, prev_si, ds, active):
        return self.scene.pdf_emitter_direction(prev_si, ds, active)


def current_sampler(sampler: LightSampler | None, scene: mi.Scene,
                    kind: type[LightSampler]) -> LightSampler:
    """``sampler``, or a new ``kind(scene)`` where it is of another kind, for another
    scene, or built for another state of the scene's shapes and emitters
    (renderers.frozen.scene_generation: its emitter powers and positions would be
    stale; a stale pmf stays positive, so it costs variance, not bias)."""
    from renderers.frozen import scene_generation

    generation = scene_generation(scene)
    if (sampler is None or sampler.scene is not scene or type(sampler) is not kind
            or sampler.generation != generation):
        sampler = kind(scene)
        sampler.generation = generation
    return sampler


def _mean_luminance(emitter: mi.Emitter, si: mi.SurfaceInteraction3f) -> float:
    value = mi.luminance(mi.unpolarized_spectrum(emitter.eval(si))) if mi.is_rgb else \
        dr.mean(emitter.eval(si))
    return float(np.mean(value.numpy()))


def emitter_powers(scene: mi.Scene) -> np.ndarray:
    """Approximate emitted power of each emitter (see the module docstring), shape (N,)."""
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(0, POWER_SAMPLES)
    u = sampler.next_2d()
    radius = scene.bbox().bounding_sphere().radius
    powers = np.full(len(scene.emitters()), np.nan)
    for i, emitter in enumerate(scene.emitters()):
        shape = emitter.get_shape()
        if emitter.is_environment():
            si = dr.zeros(mi.SurfaceInteraction3f, POWER_SAMPLES)
            si.t = dr.inf
            si.wi = mi.warp.square_to_uniform_sphere(u)
            powers[i] = 4 * dr.pi**2 * radius**2 * _mean_luminance(emitter, si)
        elif shape is not None:
            ps = shape.sample_position(0.0, u)
            si = mi.SurfaceInteraction3f(ps, dr.zeros(mi.Color0f))
            si.wi = mi.Vector3f(0, 0, 1)  # local frame: the emitting side
            powers[i] = dr.pi * float(shape.surface_area()[0]) * _mean_luminance(emitter, si)
    finite = powers[np.isfinite(powers) & (powers > 0)]
    mean = float(finite.mean()) if finite.size else 1.0
    powers[~np.isfinite(powers)] = mean
    return np.maximum(powers, POWER_FLOOR * mean)


class PowerLightSampler(LightSampler):
    """p(i) ∝ Φ_i, the same at every point (pbrt-v4 ``PowerLightSampler``)."""

    ARRAYS = (*LightSampler.ARRAYS, "distribution")

    def __init__(self, scene: mi.Scene) -> None:
        super().__init__(scene)
        self.powers = emitter_powers(scene)
        # No emitter, no distribution (Mitsuba refuses an empty one); NEE then adds
        # nothing and the pmf is never evaluated (LightSampler).
        self.distribution = (mi.DiscreteDistribution(mi.Float(self.powers)) if self.count
                             else None)

    def sample(self, si, u, active):
        index, u_x, pmf = self.distribution.sample_reuse_pmf(u, active)
        return index, pmf, u_x

    def pmf(self, si, index, active):
        return self.distribution.eval_pmf_normalized(index, active)


def invert_cdf(weights: list[mi.Float], u: mi.Float) -> tuple[mi.UInt32, mi.Float, mi.Float]:
    """(index i, w_i / sum w, ``u`` rescaled to [0, 1) within i) for u in [0, 1).

    The first i whose running sum exceeds u * sum w, in one pass over the
    weights (the distribution weighted reservoir sampling draws from); pmf 0
    where every weight is 0."""
    total = sum(weights[1:], weights[0])
    target = u * total
    index = mi.UInt32(len(weights) - 1)
    chosen_weight = weights[-1]
    below = mi.Float(0)      # running sum before the chosen entry
    running = mi.Float(0)
    found = mi.Bool(False)
    for i, weight in enumerate(weights):
        hit = ~found & (target < running + weight)
        index = dr.select(hit, i, index)
        chosen_weight = dr.select(hit, weight, chosen_weight)
        below = dr.select(hit, running, below)
        found |= hit
        running += weight
    pmf = dr.select(total > 0, chosen_weight / total, 0)
    u_x = dr.clip(dr.select(chosen_weight > 0, (target - below) / chosen_weight, 0), 0,
                  dr.one_minus_epsilon(mi.Float))
    return index, pmf, u_x


class WeightedLightSampler(LightSampler):
    """p(i | x) = w_i(x) / sum_j w_j(x) for per-point weights ``weights(si)`` (one Float per emitter).

    ``sample`` inverts the CDF of the weights in one pass over the emitters
    (the same distribution weighted reservoir sampling draws from; the pass
    also rescales ``u`` for reuse); ``pmf`` recomputes the weights at the
    given point and picks one. Where every weight is 0 (no emitter can
    contribute) both give pmf 0 and NEE does nothing.
    """

    def weights(self, si: mi.SurfaceInteraction3f, active: mi.Bool) -> list[mi.Float]:
        """w_i(x) >= 0 of every emitter, in ``scene.emitters()`` order."""
        raise NotImplementedError

    def sample(self, si, u, active):
        return invert_cdf(self.weights(si, active), u)

    def sampler_at(self, si, active):
        weights = self.weights(si, active)  # once for every draw
        return lambda u: invert_cdf(weights, u)

    def pmf(self, si, index, active):
        weights = self.weights(si, active)
        total = sum(weights[1:], weights[0])
        chosen = mi.Float(0)
        for i, weight in enumerate(weights):
            chosen = dr.select(index == i, weight, chosen)
        return dr.select(total > 0, chosen / total, 0)


class SpatialLightSampler(WeightedLightSampler):
    """p(i | x) ∝ Φ_i / max(|x - c_i|^2, r_i^2): near, bright emitters first.

    Environment emitters have no centre: their weight is Φ / R^2 at every
    point (R the scene's bounding-sphere radius), the weight of an emitter of
    the same power at the scene's edge. Each query loops over all emitters
    (unrolled into the kernel), which suits scenes of tens of emitters; pbrt-v4's
    ``BVHLightSampler`` is the O(log N) version of the same idea.
    """

    def __init__(self, scene: mi.Scene) -> None:
        super().__init__(scene)
        self.powers = emitter_powers(scene)
        radius = scene.bbox().bounding_sphere().radius
        self.terms: list[tuple[float, Any, float]] = []  # (power, centre or None, r^2) per emitter
        for power, emitter in zip(self.powers, self.emitters, strict=True):
            box = emitter.bbox()  # a scalar bounding box
            if emitter.is_environment() or not box.valid():
                self.terms.append((float(power) / radius**2, None, 0.0))
            else:
                centre = [float(c) for c in box.center()]
                r2 = max(float(dr.squared_norm(box.extents())) / 4, 1e-8)
                self.terms.append((float(power), centre, r2))

    def _weight(self, p: mi.Point3f, term: tuple[float, Any, float]) -> mi.Float:
        power, centre, r2 = term
        if centre is None:
            return mi.Float(power)
        return power * dr.rcp(dr.maximum(dr.squared_norm(p - mi.Point3f(*centre)), r2))

    def weights(self, si, active):
        return [self._weight(si.p, term) for term in self.terms]
