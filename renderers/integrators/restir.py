"""Screen-space ReSTIR DI at primary hits (`restir-di`), one reservoir per pixel.

Spatiotemporal reservoir resampling (Bitterli et al. 2020) for the direct
light at the camera rays' first hits, as the Neural Visibility Cache paper's
baseline (Sec. 4.1): 8 initial candidates, temporal reuse of the same
pixel's previous reservoir with its confidence clamped at 20x the candidates,
spatial reuse within 32 px. Everything is in the area measure on the lights:
a sample is a point y on emitter e, and the same y is a sample of every
pixel's integral (the identity shift, Jacobian 1).

Per lane (one per pixel and replica) and frame, with x the pixel's first hit:

    target      p̂_x(y) = lum(f(x, ω_o, x→y) |cos θ_x| · Le(y → x) · |cos θ_y| / |x - y|²)
                (unshadowed), and p̂V_x(y) = p̂_x(y) V(x, y) once a shadow ray was cast
    candidates  y_i ~ p(y) = P(e) · pdf_A(y | e), P the power-proportional light
                selection (renderers.integrators.lights.PowerLightSampler) or any other
                selector with an exact pmf (`restir-nvc`: the neural visibility cache's,
                clustered or per light), pdf_A the emitter's position pdf (area
                measure); i = 1..C
    RIS         w_i = p̂_x(y_i) / (C p(y_i)),  pick y_s with prob w_s / Σ w,
                W = Σ w / p̂_x(y_s) · V(x, y_s),  M = C   (the one shadow ray: an
                occluded choice keeps M and gets W = 0, so the reservoir's target
                is p̂V)
    reuse       GRIS (Lin et al. 2022) over reservoirs (y_j, W_j, M_j) of shading
                points x_j: the canonical input c = 0 (the pixel's own, at x_c = x) and
                k others i = 1..k (the previous frame's, or k neighbours'), with
                confidence-weighted pairwise MIS [Bit22]: per pair (c, i)
                the balance heuristic of c at confidence M_c / k and i at M_i,
                    a_i(y) = M_i p̂V_{x_i}(y) / (M_i p̂V_{x_i}(y) + (M_c/k) p̂V_x(y)),
                    b_i(y) = 1 - a_i(y),
                m_i(y) = a_i(y) / k,  m_c(y) = (1/k) Σ_i b_i(y),
                w_j = m_j(y_j) p̂V_x(y_j) W_j,  W = Σ w / p̂_x(y_s),  M = Σ M_j
    shading     L = Le(x) + f(x, x→y) Le(y) G(x, y) · W   (W > 0: y visible from x)
                    + f_δ(x, ω) Le(y_δ) / p(ω)   (ω drawn by the BSDF; only when the
                    drawn lobe is a delta lobe, y_δ the first hit along ω)

For every y with p̂V_x(y) > 0 the pair's denominator is positive and
Σ_i m_i + m_c = (1/k) Σ_i (a_i + b_i) = 1; an input that cannot hold y gets
m = 0 (a_i = 0 where p̂V_{x_i}(y) = 0; where p̂V_x(y) = 0 the sample's w is 0
whatever m_c is); an input with M_i = 0 (no hit at x_i) has a_i = 0, so its
pair's share goes to c. So each reservoir's W stays an unbiased
contribution weight of its target at its own x: the image is unbiased with
reuse on (docs/estimators.md, "restir-di"). The target evaluates the BSDF,
which is 0 on delta lobes (a mirror, the coating of smooth plastic, glass), so
the light reflected or refracted by a delta lobe at x is not a light sample at
all: one BSDF sample per lane adds it where the BSDF drew a delta lobe (the
second line of the shading), as Mitsuba's ``path`` at max_depth 2 collects an
emitter hit after a delta bounce with MIS weight 1. The visibility in the weights
costs 2 shadow rays per non-canonical input: p̂V_x(y_i) from x (a_i(y_i) and
w_i) and p̂V_{x_i}(y_c) from x_i (b_i(y_c)); V_{x_i}(y_i) = 1 needs none, since a
kept sample is visible from its own x_i (W_i > 0 only then). So 2k rays where
the Talbot heuristic m_j(y) = M_j p̂V_{x_j}(y) / Σ_l M_l p̂V_{x_l}(y) (estimator
versions 1 and 2) needs every pair: (k+1) k. With k = 1 (temporal reuse) both
are the same weights. The confidence weights M are clamped before
temporal reuse (M_prev <= m_clamp · C), which changes the weights, not their
sum. The path ends at the first hit: the image is the emission seen by the
camera plus direct light there (Mitsuba's ``path`` at max_depth 2). Emitters
must be area emitters (a point on a surface).

Temporal reuse along motion vectors: the previous reservoir reused at a pixel is
that of the previous frame's pixel where x was seen, found by projecting x with
the previous frame's camera (a perspective camera; :class:`Motion`). It is rejected
(M_i = 0: its pair's share goes to c, no shadow ray) where x projects off the
previous film or behind the previous camera, or where the previous first hit x_i
found there is another surface: no hit, normals more than 25° apart, or
distances from the previous camera differing by more than 10 % (the thresholds
[BWP*20] give for the pixels whose reservoirs are reused). The choice of input depends
only on x and the previous G-buffer, and the pairwise weights already take x_i ≠ x
(p̂V_{x_i} is evaluated at x_i), so the estimator stays unbiased whatever is
reused; the projection only makes x_i ≈ x, so that the previous sample is a good
one for x. While the camera stays where the history was made, the pixel's own
previous reservoir is reused as before (x_i is x up to the pixel's jitter), and
so it is with a camera that is not a perspective one.

Temporal reuse needs the previous reservoir's support: a_i(y) must be 0 where
the previous frame's p̂V_{x_i} was 0 (its sample cannot be there). The targets
are evaluated in the scene as it is now, so after an animation changed the
scene's emitters or shapes (renderers.frozen.scene_generation; a camera move
changes no target) that no longer holds: a light switched on, or a
point x_i newly unoccluded, has p̂V_{x_i}(y) > 0 now where the previous reservoir
could not have sampled y, and a_i takes a share of the canonical sample's
weight that nothing makes up (docs/estimators.md, "`restir-di`": the frame
where 8 of 32 lights of `many-lights-switch` switch on was 10 % dark). So a
frame whose scene state differs from its history's starts without temporal
reuse (the previous reservoirs, their W and M, are dropped);
spatial reuse, within the frame, is unaffected. While a shape moves
continuously every frame is such a frame: object motion is treated as a
disocclusion of every pixel (reprojecting x_i under the shape's previous pose
would find the point, but its previous target p̂V_{x_i} would need the previous
scene's geometry, which is not kept).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import drjit as dr
import mitsuba as mi
import numpy as np

from renderers.frozen import (
    Frozen,
    camera_generation,
    freezing,
    scene_generation,
    weak_method,
)
from renderers.integrators.lights import LightSampler, PowerLightSampler, current_sampler


class ReSTIRParams(Protocol):
    """What the estimator reads of the method's parameters."""

    candidates: int
    temporal: bool
    m_clamp: float
    spatial: bool
    spatial_neighbours: int
    spatial_radius: float


class Reservoir:
    """One light sample per lane: emitter index, point y on it, its weight W and confidence M."""

    DRJIT_STRUCT = {"emitter": mi.UInt32, "p": mi.Point3f, "n": mi.Normal3f,
                    "uv": mi.Point2f, "W": mi.Float, "M": mi.Float}

    def __init__(self, emitter=None, p=None, n=None, uv=None, W=None, M=None) -> None:
        self.emitter, self.p, self.n, self.uv, self.W, self.M = emitter, p, n, uv, W, M


#: Fields of a first hit the reuse never reads and the intersection leaves constant: the
#: ray's time (the camera samples at time 0), the shading normal's derivatives and the
#: texture coordinates' screen derivatives (for ray differentials; no BSDF, emitter or
#: visibility query here reads them).
UNREAD_FIELDS = ("time", "dn_du", "dn_dv", "duv_dx", "duv_dy")


class FirstHits:
    """The first hits a frame hands to the next: the fields of ``mi.SurfaceInteraction3f``
    but :data:`UNREAD_FIELDS`. Those are Dr.Jit literals (constants) in the frame; a
    frozen frame hands its literal outputs back as literals, and the next call, which
    makes its inputs opaque, writes each into memory again: a launch per field and frame
    (11 of restir-di's 23 per frame on many-lights, measured)."""

    DRJIT_STRUCT = {name: kind for name, kind in mi.SurfaceInteraction3f.DRJIT_STRUCT.items()
                    if name not in UNREAD_FIELDS}

    @classmethod
    def of(cls, si: mi.SurfaceInteraction3f) -> FirstHits:
        hits = cls()
        for name in cls.DRJIT_STRUCT:
            setattr(hits, name, getattr(si, name))
        return hits

    def interaction(self) -> mi.SurfaceInteraction3f:
        """These hits as surface interactions, the unread fields zero."""
        si = dr.zeros(mi.SurfaceInteraction3f, dr.width(self.t))
        for name in self.DRJIT_STRUCT:
            setattr(si, name, getattr(self, name))
        return si


@dataclass
class Frame:
    """What the next frame reuses: the final reservoirs and the first hits they belong to."""

    reservoirs: Reservoir
    si: FirstHits


#: A reused reservoir's first hit must face within this angle of x's ([BWP*20]: 25°) ...
MAX_NORMAL_ANGLE_DEG = 25.0
#: ... and lie at a distance from the previous camera within this fraction of x's (10 %).
MAX_DEPTH_CHANGE = 0.1


@dataclass(frozen=True)
class CameraProjection:
    """A perspective camera as numbers: world point → film pixel, and its position."""

    to_film: np.ndarray    # 4x4: (x, y, z, 1) → (u w, v w, ·, w), w the camera-space depth
    position: np.ndarray   # 3

    @classmethod
    def of(cls, sensor: mi.Sensor) -> CameraProjection | None:
        """The projection of ``sensor`` (None unless it is a perspective camera)."""
        params = mi.traverse(sensor)
        if "x_fov" not in params or "principal_point_offset_x" not in params:
            return None
        film = sensor.film()
        to_sample = mi.perspective_projection(film.size(), film.crop_size(), film.crop_offset(),
                                              float(params["x_fov"][0]), sensor.near_clip(),
                                              sensor.far_clip())
        to_world = np.array(sensor.world_transform().matrix, dtype=np.float64)[..., 0]
        to_pixels = np.diag([*film.crop_size(), 1.0, 1.0])
        offset = np.eye(4)   # the principal point's shift, in film fractions
        offset[0, 3] = -float(params["principal_point_offset_x"][0])
        offset[1, 3] = -float(params["principal_point_offset_y"][0])
        return cls(to_pixels @ offset @ np.array(to_sample.matrix, dtype=np.float64)[..., 0]
                   @ np.linalg.inv(to_world), to_world[:3, 3].copy())

    def same(self, other: CameraProjection | None) -> bool:
        return other is self or (other is not None
                                 and np.array_equal(self.to_film, other.to_film)
                                 and np.array_equal(self.position, other.position))

    def motion(self) -> Motion:
        return Motion(mi.Matrix4f(self.to_film.astype(np.float32)),
                      mi.Point3f(*(float(c) for c in self.position)))


@dataclass
class Motion:
    """The previous frame's camera, handed to a frame whose camera moved since."""

    to_film: mi.Matrix4f
    position: mi.Point3f


def reproject(si: mi.SurfaceInteraction3f, previous: Frame, motion: Motion,
              lane: mi.UInt32, size: tuple[int, int]
              ) -> tuple[mi.UInt32, mi.SurfaceInteraction3f, mi.Bool]:
    """(the previous frame's lane where each lane's first hit x was seen, the first hit
    x_i there, whether its reservoir may be reused): x projected with the previous
    camera, rejected off the film, behind the camera or where the previous first hit
    found there is another surface (module docstring)."""
    width, height = size
    pixel = lane % (width * height)
    h = motion.to_film @ mi.Vector4f(si.p.x, si.p.y, si.p.z, 1.0)
    u, v = h.x / h.w, h.y / h.w
    kept = si.is_valid() & (h.w > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    x = dr.clip(mi.Int32(dr.floor(u)), 0, width - 1)
    y = dr.clip(mi.Int32(dr.floor(v)), 0, height - 1)
    source = dr.select(kept, lane - pixel + mi.UInt32(y) * width + mi.UInt32(x), lane)
    x_i = dr.gather(FirstHits, previous.si, source).interaction()
    depth = dr.norm(si.p - motion.position)
    kept &= (x_i.is_valid()
             & (dr.dot(si.n, x_i.n) >= math.cos(math.radians(MAX_NORMAL_ANGLE_DEG)))
             & (dr.abs(dr.norm(x_i.p - motion.position) - depth) <= MAX_DEPTH_CHANGE * depth))
    return source, x_i, kept


def target(scene: mi.Scene, si: mi.SurfaceInteraction3f, r: Reservoir,
           active: mi.Bool) -> tuple[mi.Spectrum, mi.Float]:
    """(unshadowed contribution f · Le · G in the area measure, its luminance p̂) at ``si``."""
    to_light = r.p - si.p
    dist2 = dr.squared_norm(to_light)
    ds = dr.zeros(mi.DirectionSample3f)
    ds.p, ds.n, ds.uv = r.p, r.n, r.uv
    ds.dist = dr.sqrt(dist2)
    ds.d = to_light / ds.dist
    ds.emitter = dr.gather(mi.EmitterPtr, scene.emitters_dr(), r.emitter, active)
    active &= si.is_valid() & (dist2 > 0)
    Le = ds.emitter.eval_direction(si, ds, active)  # 0 on the emitter's back side
    f = si.bsdf().eval(mi.BSDFContext(), si, si.to_local(ds.d), active)  # includes |cos θ_x|
    value = dr.select(active, f * Le * dr.abs(dr.dot(ds.n, ds.d)) / dist2, 0)
    return value, mi.luminance(value)


def stream(chosen: tuple[Reservoir, mi.Float], w_sum: mi.Float,
           candidate: tuple[Reservoir, mi.Float], w: mi.Float,
           u: mi.Float) -> tuple[tuple[Reservoir, mi.Float], mi.Float]:
    """Weighted reservoir sampling of (sample, its target p̂_x): keep ``candidate`` with
    probability w / (w_sum + w)."""
    w_sum = w_sum + w
    return dr.select(u * w_sum < w, candidate, chosen), w_sum


def finish(chosen: tuple[Reservoir, mi.Float], w_sum: mi.Float, M: mi.Float,
           active: mi.Bool) -> Reservoir:
    """The reservoir's unbiased contribution weight W = Σ w / p̂_x(y_s) (0 where p̂ = 0),
    p̂_x(y_s) streamed with the sample (not evaluated again)."""
    chosen, p_hat = chosen
    chosen.W = dr.select(active & (p_hat > 0), w_sum / p_hat, 0)
    chosen.M = dr.select(active, M, 0)
    return chosen


def visible(scene: mi.Scene, si: mi.SurfaceInteraction3f, r: Reservoir,
            active: mi.Bool) -> mi.Bool:
    """V(x, y): one shadow ray from ``si`` to the reservoir's light point (False where inactive)."""
    return active & ~scene.ray_test(si.spawn_ray_to(r.p), active)


def initial(scene: mi.Scene, lights: LightSampler, si: mi.SurfaceInteraction3f,
            sampler: mi.Sampler, candidates: int) -> Reservoir:
    """RIS of ``candidates`` light samples y ~ P(e) pdf_A(y | e) toward p̂_x."""
    active = si.is_valid()
    chosen, w_sum = (dr.zeros(Reservoir, dr.width(active)), mi.Float(0)), mi.Float(0)
    draw = lights.sampler_at(si, active)  # per-point selection weights, once
    for _ in range(candidates):
        index, pmf, _ = draw(sampler.next_1d(active))
        emitter = dr.gather(mi.EmitterPtr, scene.emitters_dr(), index, active)
        ps, _ = emitter.sample_position(0.0, sampler.next_2d(active), active)
        candidate = Reservoir(index, ps.p, ps.n, ps.uv, mi.Float(0), mi.Float(0))
        _, p_hat = target(scene, si, candidate, active)
        source = pmf * ps.pdf  # area measure
        w = dr.select(active & (source > 0), p_hat / (candidates * source), 0)
        chosen, w_sum = stream(chosen, w_sum, (candidate, p_hat), w, sampler.next_1d(active))
    chosen = finish(chosen, w_sum, mi.Float(candidates), active)
    # The one shadow ray: an occluded choice keeps its M but gets W = 0 (visibility reuse).
    chosen.W = dr.select(visible(scene, si, chosen, active & (chosen.W > 0)), chosen.W, 0)
    return chosen


def visible_target(scene: mi.Scene, si: mi.SurfaceInteraction3f, r: Reservoir,
                   active: mi.Bool) -> mi.Float:
    """p̂V_x(y) = p̂_x(y) V(x, y): the shadow ray only where p̂_x(y) > 0 (0 where inactive)."""
    _, p_hat = target(scene, si, r, active)
    return dr.select(visible(scene, si, r, active & (p_hat > 0)), p_hat, 0)


def balance(mine: mi.Float, other: mi.Float) -> mi.Float:
    """The two-strategy balance heuristic mine / (mine + other) (0 where both are 0)."""
    total = mine + other
    return dr.select(total > 0, mine / total, 0)


def combine(scene: mi.Scene, si: mi.SurfaceInteraction3f,
            inputs: list[tuple[Reservoir, mi.SurfaceInteraction3f]],
            sampler: mi.Sampler) -> Reservoir:
    """GRIS of ``inputs`` (reservoir, its shading point; the pixel's own first, the
    canonical input c) toward p̂V at ``si`` with pairwise MIS [Bit22] (module
    docstring): 2 shadow rays per non-canonical input."""
    active = si.is_valid()
    (canonical, _), others = inputs[0], inputs[1:]
    k = len(others)
    share = canonical.M / k  # the canonical input's confidence in each of its k pairs
    chosen, w_sum = (dr.zeros(Reservoir, dr.width(active)), mi.Float(0)), mi.Float(0)
    # p̂V_c(y_c) = p̂_c(y_c): a kept sample is visible from its own point (W > 0 only then)
    _, p_c_yc = target(scene, si, canonical, active & (canonical.W > 0))
    m_c = mi.Float(0)
    for r, si_i in others:
        # The canonical sample's share of pair i: b_i(y_c) = (M_c/k) p̂V_c / (M_i p̂V_i + (M_c/k) p̂V_c)
        p_i_yc = visible_target(scene, si_i, canonical, active & (r.M > 0) & (canonical.W > 0))
        m_c += balance(share * p_c_yc, r.M * p_i_yc)
        # Neighbour i's sample: m_i(y_i) = a_i(y_i) / k, a_i = M_i p̂V_i / (M_i p̂V_i + (M_c/k) p̂V_c),
        # V_i(y_i) = 1 for a kept sample; w_i = m_i(y_i) p̂V_c(y_i) W_i
        live = active & (r.M > 0) & (r.W > 0)
        _, p_i_yi = target(scene, si_i, r, live)
        p_c_yi = visible_target(scene, si, r, live)
        w = balance(r.M * p_i_yi, share * p_c_yi) / k * p_c_yi * r.W
        chosen, w_sum = stream(chosen, w_sum, (r, p_c_yi), w, sampler.next_1d(active))
    # m_c(y_c) = (1/k) Σ_i b_i(y_c); w_c = m_c(y_c) p̂V_c(y_c) W_c
    w = m_c / k * p_c_yc * canonical.W
    chosen, w_sum = stream(chosen, w_sum, (canonical, p_c_yc), w, sampler.next_1d(active))
    M = sum((r.M for r, _ in others), canonical.M)
    # A chosen sample has w > 0, so it is visible from x: W = Σ w / p̂_x(y_s).
    return finish(chosen, w_sum, M, active)


def delta_emission(scene: mi.Scene, si: mi.SurfaceInteraction3f, sampler: mi.Sampler,
                   active: mi.Bool) -> mi.Spectrum:
    """The emission seen from ``si`` through a delta lobe of its BSDF: one BSDF sample,
    kept only where it drew a delta lobe (f_δ Le / p, the sample weight dividing by the
    lobe's selection probability too); the reservoirs' target holds every other lobe."""
    ctx = mi.BSDFContext()
    bs, bsdf_weight = si.bsdf().sample(ctx, si, sampler.next_1d(active),
                                       sampler.next_2d(active), active)
    delta = active & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
    hit = scene.ray_intersect(si.spawn_ray(si.to_world(bs.wo)), delta)
    return dr.select(delta, bsdf_weight * hit.emitter(scene, delta).eval(hit, delta), 0)


def neighbour_lanes(sampler: mi.Sampler, lane: mi.UInt32, size: tuple[int, int],
                    radius: float) -> mi.UInt32:
    """A pixel uniform in the disk of ``radius`` px around each lane's (clamped to the
    film), in the same replica."""
    width, height = size
    pixel = lane % (width * height)
    base = lane - pixel
    offset = mi.warp.square_to_uniform_disk(sampler.next_2d()) * radius
    x = dr.clip(mi.Int32(dr.round(mi.Float(pixel % width) + offset.x)), 0, width - 1)
    y = dr.clip(mi.Int32(dr.round(mi.Float(pixel // width) + offset.y)), 0, height - 1)
    return base + mi.UInt32(y) * width + mi.UInt32(x)


class ReSTIRDI:
    """The estimator's frame: G-buffer, candidates, temporal and spatial reuse, shading.

    ``replicas`` independent images of the film's size are rendered side by side
    (lane = replica · pixels + pixel), each with its own reservoirs: the method's
    spp, and what the statistical tests average over.

    A frame (:meth:`frame`) is a function of its seed, the previous frame's
    reservoirs and the light selector's data, all Dr.Jit values passed in and
    returned, so it can be frozen (renderers.frozen): it is, unless the selector
    reads state held in Python (``LightSampler.stateful``, `restir-nvc`'s cache)
    or freezing is off. The history carried between frames is :attr:`history`,
    made in the scene state :attr:`history_state` (module docstring: it is
    dropped when the state changed) and seen by the camera :attr:`history_camera`
    (a frame whose camera moved since reuses it along motion vectors).
    """

    def __init__(self, scene: mi.Scene, params: ReSTIRParams, replicas: int = 1,
                 lights: LightSampler | None = None) -> None:
        self.scene, self.params, self.replicas = scene, params, replicas
        self.size = tuple(int(s) for s in scene.sensors()[0].film().crop_size())
        # The candidates' light selection (its pmf enters the RIS weights): by power.
        self.lights = PowerLightSampler(scene) if lights is None else lights
        self.history: Frame | None = None
        self.history_state: tuple[int, str] | None = None
        self.history_camera: CameraProjection | None = None
        # The sensor's projection and the camera generation it was computed in: computed
        # again only after the camera changed (renderers.frozen.camera_changed), not in
        # every timed frame (mi.traverse and matrix work on the host, 0.3-0.8 ms).
        self._camera: tuple[int, CameraProjection | None] | None = None
        self._frame = (Frozen(weak_method(self.frame), auto_opaque=False)
                       if freezing() and not self.lights.stateful else self.frame)

    def recordings(self) -> int | None:
        """Recordings of the frozen frame (None when it is not frozen)."""
        return self._frame.recordings() if isinstance(self._frame, Frozen) else None

    def reset(self) -> None:
        """Forget the previous frame (no temporal reuse in the next one)."""
        self.history = None

    def first_hits(self, scene: mi.Scene, sampler: mi.Sampler,
                   lane: mi.UInt32) -> tuple[mi.SurfaceInteraction3f, mi.Spectrum]:
        """Each lane's camera ray through a uniform point of its pixel (box filter):
        (first hit, sensor weight)."""
        width, height = self.size
        pixel = lane % (width * height)
        film = (mi.Point2f(mi.Float(pixel % width), mi.Float(pixel // width))
                + sampler.next_2d()) / mi.ScalarVector2f(width, height)
        ray, weight = scene.sensors()[0].sample_ray(0.0, sampler.next_1d(), film,
                                                    sampler.next_2d())
        return scene.ray_intersect(ray), weight

    def render(self, seed: int) -> mi.TensorXf:
        """One frame, its reservoirs kept for the next: a (replicas, height, width, 4)
        tensor of RGB and whether a surface was hit."""
        # Built again after the scene's emitters or shapes changed (an animation's update).
        self.lights = current_sampler(self.lights, self.scene, type(self.lights))
        state = scene_generation(self.scene)
        if state != self.history_state:  # reservoirs of another scene state: no temporal reuse
            self.history = None
        self.history_state = state
        camera = self.camera()
        moved = (self.history is not None and camera is not None
                 and not camera.same(self.history_camera))
        motion = self.history_camera.motion() if moved else None
        self.history_camera = camera
        image, self.history = self._frame(self.scene, mi.UInt32(seed), self.history,
                                          self.lights.frame_arrays(), motion)
        return image

    def camera(self) -> CameraProjection | None:
        """The sensor's projection now (None: not a perspective camera)."""
        generation = camera_generation(self.scene)
        if self._camera is None or self._camera[0] != generation:
            self._camera = (generation, CameraProjection.of(self.scene.sensors()[0]))
        return self._camera[1]

    def frame(self, scene: mi.Scene, seed: mi.UInt32, history: Frame | None,
              lights: dict[str, Any], motion: Motion | None = None
              ) -> tuple[mi.TensorXf, Frame]:
        """One frame of ``scene`` from the previous frame's reservoirs (None: no temporal
        reuse), the light selector's data (``LightSampler.frame_arrays``) and the camera
        the history was seen by where it differs from this frame's (None: each pixel
        reuses its own previous reservoir): (image, this frame's reservoirs). Reads no
        other Dr.Jit value."""
        self.lights.bind(lights)
        width, height = self.size
        n = self.replicas * width * height
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed, n)
        lane = dr.arange(mi.UInt32, n)
        si, weight = self.first_hits(scene, sampler, lane)
        valid = si.is_valid()
        reservoir = initial(scene, self.lights, si, sampler, self.params.candidates)

        if self.params.temporal and history is not None:
            clamp = self.params.m_clamp * self.params.candidates
            if motion is None:
                previous = dr.gather(Reservoir, history.reservoirs, lane)
                previous.M = dr.minimum(previous.M, clamp)
                x_i = history.si.interaction()
            else:
                source, x_i, kept = reproject(si, history, motion, lane, self.size)
                previous = dr.gather(Reservoir, history.reservoirs, source)
                previous.M = dr.select(kept, dr.minimum(previous.M, clamp), 0)
            reservoir = combine(scene, si, [(reservoir, si), (previous, x_i)], sampler)
        if self.params.spatial:
            # The neighbours gather from the reservoirs and the first hits: evaluate both in
            # one kernel. A gather from an unevaluated array evaluates that array alone, so
            # each of the hit's ~30 fields was a kernel of its own that traced the camera
            # ray again (measured: 79 launches per frame instead of 23, 3x the kernel time).
            dr.eval(reservoir, si)
            inputs = [(reservoir, si)]
            for _ in range(self.params.spatial_neighbours):
                other = neighbour_lanes(sampler, lane, self.size, self.params.spatial_radius)
                inputs.append((dr.gather(Reservoir, reservoir, other),
                               dr.gather(mi.SurfaceInteraction3f, si, other)))
            reservoir = combine(scene, si, inputs, sampler)

        dr.eval(reservoir, si)
        # W > 0 only for a sample visible from x: shading needs no further ray.
        value, _ = target(scene, si, reservoir, valid & (reservoir.W > 0))
        L = (si.emitter(scene).eval(si, valid) + value * reservoir.W
             + delta_emission(scene, si, sampler, valid))
        rgb = mi.Color3f(L * weight)
        pixels = mi.Vector4f(rgb.x, rgb.y, rgb.z, dr.select(valid, 1.0, 0.0))
        image = mi.TensorXf(dr.ravel(pixels), shape=(self.replicas, height, width, 4))
        return image, Frame(reservoir, FirstHits.of(si))


def check_scene(scene: mi.Scene) -> None:
    """Raise ValueError unless every emitter is an area emitter (a point y on a surface)."""
    if not scene.emitters():
        raise ValueError("restir-di needs at least one emitter")
    for emitter in scene.emitters():
        if emitter.get_shape() is None:
            raise ValueError("restir-di samples points on area emitters; environment and "
                             "delta emitters have none")
