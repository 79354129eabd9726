"""Light selection by a neural visibility cache (`nvc-lights`).

Neural Visibility Cache paper (Bokšanský & Meister), Sec. 3: a hash-grid +
MLP network predicts, for a position x, the visibility V_l(x) in [0, 1] of
every light l (one sigmoid output per light), trained online on shadow rays;
NEE picks a light with probability proportional to its unshadowed
contribution times that visibility (Sec. 3.1, the integrand of Eq. 1 without
V replaced by the prediction):

    w_l(x) = U_l(x) * max(V_l(x), clamp),      p(l | x) = w_l(x) / sum_k w_k(x)

The clamp (0.001, Sec. 3.1 and Fig. 5) keeps every light that can contribute
selectable, so a wrong prediction costs variance, never bias.

U_l(x), the unshadowed term. The paper uses LTC shading [HDHN16] of the
light's polygon times its radiance. Here it is the spatial selector's
power / squared distance (:class:`renderers.integrators.lights.SpatialLightSampler`:
Φ_l / max(|x - c_l|^2, r_l^2), c_l and r_l the centre and half diagonal of the
emitter's bounding box) times an upper bound of the cosine at x over that
bounding sphere (pbrt-v4's ``LightBounds::Importance``, PBR 4th ed.
Sec. 12.6.3): cos(max(θ - θ_r, 0)), θ the angle between the shading normal
(turned to the side light arrives from, the side of w_i) and the direction to
c_l, sin θ_r = r_l / |x - c_l|. Why this and not LTC or the BSDF: it needs no
per-light BSDF evaluation (32 per query, twice per vertex: for NEE and for the
MIS pdf at the previous vertex), it works for any BSDF, emitter shape and
environment emitters (weight Φ / R^2, cosine 1), and it is never 0 for a light
that can reach x — the bound is 0 only when the whole bounding sphere is
behind the surface of a reflection-only BSDF, where the contribution is 0
too (BSDFs with a transmission lobe take the bound over both sides). It
ignores the BSDF's lobe shape (glossy surfaces get a diffuse-like
selection), which costs variance, not bias.

Training data (Sec. 3.3): every frame, ``world_points`` positions uniform in
the scene's bounding box ("random positions in the scene", the paper's
world-space data) and ``camera_points`` first hits of camera rays through
uniformly random film positions (screen-space data, which removes the
world-space-only "dark blobs" of Fig. 4). From each point one shadow ray per
light toward one point sampled on it (``emitter.sample_direction``): the
target is 1 if the sample is unoccluded and emits toward x (a one-sided area
light seen from behind counts as not visible), else 0. The network learns
the mean over the light's samples, i.e. soft shadows.
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi

from renderers.caches import TrainingRecords
from renderers.integrators.lights import SpatialLightSampler
from renderers.seeding import derive_seed

#: The paper's clamp of the predicted visibility (Sec. 3.1, Fig. 5).
DEFAULT_CLAMP = 1e-3


def cosine_bound(si: mi.SurfaceInteraction3f, centre: mi.Point3f, r2: float,
                 both_sides: mi.Bool) -> mi.Float:
    """Upper bound of the cosine at ``si`` toward a sphere (centre, radius^2 r2).

    cos(max(θ - θ_r, 0)) with cos θ between the shading normal turned toward
    w_i (both sides where ``both_sides``) and the centre, sin^2 θ_r = r2 / d^2;
    1 inside the sphere, clamped at 0.
    """
    to_light = centre - si.p
    d2 = dr.squared_norm(to_light)
    facing = dr.mulsign(si.sh_frame.n, mi.Frame3f.cos_theta(si.wi))
    cos_theta = dr.dot(facing, to_light) * dr.rsqrt(d2)
    cos_theta = dr.select(both_sides, dr.abs(cos_theta), cos_theta)
    sin2_r = dr.minimum(r2 / d2, 1.0)
    cos_r = dr.safe_sqrt(1 - sin2_r)
    sin_theta = dr.safe_sqrt(1 - dr.square(cos_theta))
    # cos(θ - θ_r) = cos θ cos θ_r + sin θ sin θ_r, and 1 once θ <= θ_r.
    bound = dr.select(cos_theta >= cos_r, 1.0, cos_theta * cos_r + sin_theta * dr.sqrt(sin2_r))
    return dr.select(d2 <= r2, 1.0, dr.maximum(bound, 0.0))


class NVCLightSampler(SpatialLightSampler):
    """w_l(x) = U_l(x) * max(V_l(x), clamp), V from a visibility cache (module docstring).

    The cache and the clamp are class attributes: :meth:`bound_to` makes the
    class the PT core instantiates per scene (``light_sampler_type``), so NEE
    and the MIS pdf use one object, and every frame queries the cache's
    latest weights.
    """

    cache: Any = None
    clamp: float = DEFAULT_CLAMP

    @classmethod
    def bound_to(cls, cache: Any, clamp: float = DEFAULT_CLAMP) -> type[NVCLightSampler]:
        """A subclass whose weights use ``cache`` (one output per emitter) and ``clamp``."""
        return type(cls.__name__, (cls,), {"cache": cache, "clamp": float(clamp)})

    def __init__(self, scene: mi.Scene) -> None:
        super().__init__(scene)
        if self.cache is None or self.cache.n_outputs != self.count:
            raise ValueError("NVCLightSampler needs a visibility cache with one output per "
                             f"emitter ({self.count}): use NVCLightSampler.bound_to(cache)")

    def unshadowed(self, si: mi.SurfaceInteraction3f) -> list[mi.Float]:
        """U_l(x): power / squared distance times the cosine bound (module docstring)."""
        both_sides = mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Transmission)
        terms = []
        for term in self.terms:
            _, centre, r2 = term
            cosine = 1.0 if centre is None else cosine_bound(si, mi.Point3f(*centre), r2,
                                                             both_sides)
            terms.append(self._weight(si.p, term) * cosine)
        return terms

    def visibility(self, p: mi.Point3f) -> list[mi.Float]:
        """V_l(x) of every light: the cache's sigmoid outputs at ``p``."""
        return self.cache.query_outputs(self.cache.surface_features(p))

    def weights(self, si, active):
        return [u * dr.maximum(v, self.clamp)
                for u, v in zip(self.unshadowed(si), self.visibility(si.p), strict=True)]


def visibility_records(scene: mi.Scene, world_points: int, camera_points: int,
                       seed: int) -> TrainingRecords:
    """One frame of training data: positions and per-light 0/1 visibility (module docstring)."""
    n = world_points + camera_points
    count = len(scene.emitters())
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(dr.opaque(mi.UInt32, seed), n)

    # World-space points: uniform in the scene's bounding box.
    box = scene.bbox()
    u = mi.Vector3f(sampler.next_1d(), *sampler.next_2d())
    p_world = box.min + u * (box.max - box.min)
    # Screen-space points: first hits of rays through uniformly random film positions.
    ray, _ = scene.sensors()[0].sample_ray(time=0.0, sample1=sampler.next_1d(),
                                           sample2=sampler.next_2d(), sample3=sampler.next_2d())
    hit = scene.ray_intersect(ray)
    world = dr.arange(mi.UInt32, n) < world_points
    position = dr.select(world, p_world, hit.p)
    normal = dr.select(world, mi.Normal3f(0), hit.n)  # no offset for points off surfaces

    # One shadow ray per (point, light), lane = point * count + light.
    lane = dr.arange(mi.UInt32, n * count)
    point, light = lane // count, lane % count
    si = dr.zeros(mi.SurfaceInteraction3f, n * count)
    si.p = dr.gather(mi.Point3f, position, point)
    si.n = dr.gather(mi.Normal3f, normal, point)
    sampler.seed(dr.opaque(mi.UInt32, derive_seed(seed, "shadow rays")), n * count)
    emitter = dr.gather(mi.EmitterPtr, scene.emitters_dr(), light)
    ds, weight = emitter.sample_direction(si, sampler.next_2d(), True)
    visible = (ds.pdf > 0) & (dr.max(mi.unpolarized_spectrum(weight)) > 0)
    visible &= ~scene.ray_test(si.spawn_ray_to(ds.p), visible)

    visible = dr.select(visible, 1.0, 0.0)
    dr.eval(visible)  # once, not once per gather below
    target = [dr.gather(mi.Float, visible, dr.arange(mi.UInt32, n) * count + i)
              for i in range(count)]
    records = TrainingRecords(position=position, target=target, valid=world | hit.is_valid())
    dr.eval(records.position, records.target, records.valid)
    return records
