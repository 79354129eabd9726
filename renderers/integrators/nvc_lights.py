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

Clustered NVC (Sec. 3.4, :class:`ClusteredNVCLightSampler`). With more lights
than outputs, k-means over the emitters' bounding-box centres
(:func:`cluster_lights`; environment emitters, which have no position, get a
cluster each) groups them into K clusters, and output c predicts the mean
visibility V_c(x) of cluster c: its training target per point is the 0/1
visibility of one light drawn uniformly in the cluster (the paper's "randomly
select a light source within each cluster") toward one point on it. NEE then
picks in two steps:

    cluster     P(c | x) = W_c(x) / sum_k W_k(x),  W_c = U_c(x) * max(V_c(x), clamp)
                (exact; U_c: the unshadowed term of a light of the cluster's total
                power at its bounding sphere, as U_l for one light)
    light       streaming RIS (Talbot et al. 2005) over M candidates l_j drawn
                uniformly in c, source pmf p(l) = P(c | x) / m_c (Sec. 3.4; the paper's
                m w(y) / w_sum is the same P(c | x) in reservoir notation), target
                p̂(l) = U_l(x); pick l_s with probability p̂(l_s) / sum_j p̂(l_j), and
                W = (1 / p̂(l_s)) (1/M) sum_j p̂(l_j) / p(l_j)

W is an unbiased contribution weight (E[g(l_s) W] = sum of g over the lights
of clusters with P(c | x) > 0 and p̂ > 0, which holds every light that can
contribute: the clamp keeps P(c | x) > 0, and U_l = 0 only where the light
cannot contribute). The pmf of the pick itself is not tractable (it is a RIS
distribution), so NEE weights by W and the MIS weights of both strategies use
the exact source pmf p(l) = P(c | x) / m_c instead (``LightSampler.select``):
MIS weights need only sum to one, so the estimator stays unbiased; only how
well they balance the strategies depends on that choice. ``sample``/``pmf``
are the source itself (one light uniform in the picked cluster, exact pmf):
the candidate source of ReSTIR (`restir-nvc`). The M candidates and the
emitter's point use pseudo-random numbers hashed (TEA) from NEE's two sample
dimensions, since the PT core hands a light selector only those two.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from renderers.caches import TrainingRecords
from renderers.frozen import FrozenRecords
from renderers.integrators.lights import SpatialLightSampler, invert_cdf
from renderers.seeding import derive_seed

#: The paper's clamp of the predicted visibility (Sec. 3.1, Fig. 5).
DEFAULT_CLAMP = 1e-3
#: Streaming RIS candidates within the picked cluster (our choice; the paper gives none).
DEFAULT_CLUSTER_CANDIDATES = 8


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

    def frame_arrays(self) -> dict[str, Any]:
        """The selector's tables and the cache's current weights (they change every
        frame: a frozen frame must be handed them each time)."""
        return {**super().frame_arrays(), "cache": self.cache.inference_state()}

    def bind(self, arrays: dict[str, Any]) -> None:
        super().bind(arrays)
        self.cache.bind_inference(arrays["cache"])

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


@dataclass(frozen=True)
class LightClusters:
    """A partition of the emitters: ``labels[i]`` is emitter i's cluster, 0..count-1,
    every cluster non-empty."""

    labels: np.ndarray

    @property
    def count(self) -> int:
        return int(self.labels.max()) + 1

    def members(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(emitters sorted by cluster, each cluster's size, its first position in that order)."""
        order = np.argsort(self.labels, kind="stable").astype(np.uint32)
        sizes = np.bincount(self.labels, minlength=self.count).astype(np.uint32)
        starts = (np.cumsum(sizes) - sizes).astype(np.uint32)
        return order, sizes, starts


def cluster_lights(scene: mi.Scene, clusters: int, seed: int = 0) -> LightClusters:
    """k-means (Lloyd, k-means++ seeding, fixed ``seed``) of the emitters' bounding-box
    centres into at most ``clusters`` clusters; emitters without a position
    (environment) get one cluster each. Empty clusters are dropped."""
    from scipy.cluster.vq import kmeans2

    emitters = scene.emitters()
    placed = [i for i, e in enumerate(emitters) if not e.is_environment() and e.bbox().valid()]
    unplaced = [i for i in range(len(emitters)) if i not in set(placed)]
    labels = np.zeros(len(emitters), dtype=np.int64)
    k = max(min(clusters - len(unplaced), len(placed)), 1 if placed else 0)
    if placed:
        centres = np.array([list(emitters[i].bbox().center()) for i in placed], dtype=np.float64)
        if k == len(placed):
            assigned = np.arange(k)
        else:
            _, assigned = kmeans2(centres, k, minit="++", seed=np.random.default_rng(seed))
        labels[placed] = np.unique(assigned, return_inverse=True)[1]
    first = int(labels[placed].max()) + 1 if placed else 0
    labels[unplaced] = first + np.arange(len(unplaced))
    return LightClusters(labels)


class ClusteredNVCLightSampler(NVCLightSampler):
    """The clustered NVC (module docstring): cluster by W_c, then RIS within it.

    ``terms`` (the spatial selector's (power, centre, r^2)) are the clusters':
    the inherited ``unshadowed`` and ``weights`` are U_c and W_c; the lights' own
    terms are gathered by index for the RIS target.
    """

    clusters: LightClusters | None = None
    candidates: int = DEFAULT_CLUSTER_CANDIDATES
    ARRAYS = (*NVCLightSampler.ARRAYS, "light_power", "light_r2", "light_centre",
              "light_placed", "order", "sizes", "starts", "labels")

    @classmethod
    def bound_to_clusters(cls, cache: Any, clusters: LightClusters,
                          clamp: float = DEFAULT_CLAMP,
                          candidates: int = DEFAULT_CLUSTER_CANDIDATES,
                          ) -> type[ClusteredNVCLightSampler]:
        """A subclass whose weights use ``cache`` (one output per cluster of ``clusters``)."""
        return type(cls.__name__, (cls,), {"cache": cache, "clusters": clusters,
                                           "clamp": float(clamp), "candidates": int(candidates)})

    def __init__(self, scene: mi.Scene) -> None:
        SpatialLightSampler.__init__(self, scene)
        if (self.clusters is None or self.cache is None or len(self.clusters.labels) != self.count
                or self.cache.n_outputs != self.clusters.count):
            raise ValueError("ClusteredNVCLightSampler needs light clusters of the scene's "
                             f"{self.count} emitters and a visibility cache with one output per "
                             "cluster: use ClusteredNVCLightSampler.bound_to_clusters")
        lights = self.terms
        self.light_power = mi.Float([power for power, _, _ in lights])
        self.light_r2 = mi.Float([r2 for _, _, r2 in lights])
        centres = np.array([c if c is not None else [0.0] * 3 for _, c, _ in lights])
        self.light_centre = mi.Point3f(*(mi.Float(centres[:, k]) for k in range(3)))
        self.light_placed = mi.Bool([c is not None for _, c, _ in lights])
        order, sizes, starts = self.clusters.members()
        self.order, self.sizes, self.starts = mi.UInt32(order), mi.UInt32(sizes), mi.UInt32(starts)
        self.labels = mi.UInt32(self.clusters.labels.astype(np.uint32))
        self.terms = [self._cluster_term([lights[i] for i in np.flatnonzero(
            self.clusters.labels == c)]) for c in range(self.clusters.count)]

    @staticmethod
    def _cluster_term(members: list[tuple[float, Any, float]]) -> tuple[float, Any, float]:
        """(total power, centre, r^2) of the sphere around the members' spheres."""
        power = sum(p for p, _, _ in members)
        if any(c is None for _, c, _ in members):  # an environment: its own cluster
            return power, None, 0.0
        centres = np.array([c for _, c, _ in members])
        radii = np.sqrt([r2 for _, _, r2 in members])
        centre = (centres.min(axis=0) + centres.max(axis=0)) / 2
        radius = float(np.max(np.linalg.norm(centres - centre, axis=1) + radii))
        return power, [float(c) for c in centre], radius**2

    def light_unshadowed(self, si: mi.SurfaceInteraction3f, index: mi.UInt32,
                         both_sides: mi.Bool, active: mi.Bool) -> mi.Float:
        """U_l(x) of emitter ``index`` per lane (``unshadowed``'s terms, gathered)."""
        power = dr.gather(mi.Float, self.light_power, index, active)
        centre = dr.gather(mi.Point3f, self.light_centre, index, active)
        r2 = dr.gather(mi.Float, self.light_r2, index, active)
        placed = dr.gather(mi.Bool, self.light_placed, index, active)
        near = power * dr.rcp(dr.maximum(dr.squared_norm(si.p - centre), r2))
        value = near * cosine_bound(si, centre, r2, both_sides)
        return dr.select(active, dr.select(placed, value, power), 0)

    def _uniform_member(self, cluster: mi.UInt32, p_cluster: mi.Float,
                        u: mi.Float) -> tuple[mi.UInt32, mi.Float, mi.Float]:
        """A light uniform in ``cluster``: (index, P(c) / m_c, ``u`` rescaled)."""
        size = dr.gather(mi.UInt32, self.sizes, cluster)
        k = dr.minimum(mi.UInt32(u * mi.Float(size)), size - 1)
        index = dr.gather(mi.UInt32, self.order, dr.gather(mi.UInt32, self.starts, cluster) + k)
        u_x = dr.clip(u * mi.Float(size) - mi.Float(k), 0, dr.one_minus_epsilon(mi.Float))
        return index, p_cluster / mi.Float(size), u_x

    def sample(self, si, u, active):
        return self._uniform_member(*invert_cdf(self.weights(si, active), u))

    def sampler_at(self, si, active):
        weights = self.weights(si, active)  # once for every draw
        return lambda u: self._uniform_member(*invert_cdf(weights, u))

    def pmf(self, si, index, active):
        weights = self.weights(si, active)
        total = sum(weights[1:], weights[0])
        cluster = dr.gather(mi.UInt32, self.labels, index, active)
        chosen = mi.Float(0)
        for c, weight in enumerate(weights):
            chosen = dr.select(cluster == c, weight, chosen)
        size = mi.Float(dr.gather(mi.UInt32, self.sizes, cluster, active))
        return dr.select(active & (total > 0), chosen / (total * size), 0)

    def select(self, si, u, active):
        """Cluster by W_c, streaming RIS within it: (l_s, W, p(l_s), u for the emitter)."""
        cluster, p_cluster, _ = invert_cdf(self.weights(si, active), u.x)
        key, _ = mi.sample_tea_32(dr.reinterpret_array(mi.UInt32, u.x),
                                  dr.reinterpret_array(mi.UInt32, u.y))

        def rnd(i: int) -> mi.Float:
            return mi.sample_tea_float32(key, mi.UInt32(i))

        both_sides = mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Transmission)
        m = self.candidates
        chosen, chosen_hat, w_sum, source = mi.UInt32(0), mi.Float(0), mi.Float(0), mi.Float(0)
        for j in range(m):
            index, source, _ = self._uniform_member(cluster, p_cluster, rnd(2 * j))
            p_hat = self.light_unshadowed(si, index, both_sides, active)
            w_sum += p_hat  # / (M p(l_j)): p(l_j) = P(c) / m_c is the same for every j
            keep = (rnd(2 * j + 1) * w_sum < p_hat) | (j == 0)
            chosen = dr.select(keep, index, chosen)
            chosen_hat = dr.select(keep, p_hat, chosen_hat)
        weight = dr.select((chosen_hat > 0) & (source > 0), w_sum / (m * source * chosen_hat), 0)
        return chosen, weight, source, mi.Point2f(rnd(2 * m), rnd(2 * m + 1))


def visibility_records(scene: mi.Scene, world_points: int, camera_points: int,
                       seed: int, clusters: LightClusters | None = None) -> TrainingRecords:
    """One frame of training data: positions and 0/1 visibility per light, or per cluster
    of ``clusters`` toward one light uniform in it (module docstring)."""
    return VisibilityRecords(world_points, camera_points, clusters, frozen=False)(scene, seed)


class VisibilityRecords(FrozenRecords):
    """:func:`visibility_records` of a cache's settings, frozen (renderers.frozen) where
    freezing is on: the seeds and the clusters' tables are the recording's arguments."""

    def __init__(self, world_points: int, camera_points: int,
                 clusters: LightClusters | None, frozen: bool | None = None) -> None:
        self.world_points, self.camera_points, self.clusters = (world_points, camera_points,
                                                                clusters)
        # The clusters' tables on the device once, not every frame.
        self.members = (None if clusters is None
                        else tuple(mi.UInt32(a) for a in clusters.members()))
        super().__init__(frozen)

    def arguments(self, seed: int) -> tuple[Any, ...]:
        return (dr.opaque(mi.UInt32, seed),
                dr.opaque(mi.UInt32, derive_seed(seed, "shadow rays")), self.members)

    def records(self, scene: mi.Scene, seed: mi.UInt32, shadow_seed: mi.UInt32,
                members: tuple[mi.UInt32, ...] | None) -> TrainingRecords:
        world_points, camera_points = self.world_points, self.camera_points
        n = world_points + camera_points
        count = len(scene.emitters()) if self.clusters is None else self.clusters.count
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed, n)

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

        # One shadow ray per (point, output), lane = point * count + output.
        lane = dr.arange(mi.UInt32, n * count)
        point, light = lane // count, lane % count
        si = dr.zeros(mi.SurfaceInteraction3f, n * count)
        si.p = dr.gather(mi.Point3f, position, point)
        si.n = dr.gather(mi.Normal3f, normal, point)
        sampler.seed(shadow_seed, n * count)
        if members is not None:  # output = cluster: one of its lights, uniformly
            order, sizes, starts = members
            size = dr.gather(mi.UInt32, sizes, light)
            k = dr.minimum(mi.UInt32(sampler.next_1d() * mi.Float(size)), size - 1)
            light = dr.gather(mi.UInt32, order, dr.gather(mi.UInt32, starts, light) + k)
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
