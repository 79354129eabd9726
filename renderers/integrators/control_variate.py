"""Control variates with a closed-form integral at the camera rays' first hits.

NIRC paper Eq. 7 and Sec. 6.1: a control variate g with a known integral G turns
the one-sample estimate of an integral F = int f into

    <F> = G + (f(w) - g(w)) / q(w),        w ~ q,                       (Eq. 7)

unbiased for *any* g that does not depend on w, provided q(w) > 0 wherever
f - g != 0. As NIRC splits the incident light (Eq. 8: L_i = L_ind + L_nee), the
pixel's radiance at the first hit x of a camera ray is

    L = L_e(x) + <L_nee(x)> + G_p + (f(w) - g_p(w)) / q(w),
    f(w) = L_ind(x, w) f_s(x, w, w_o) |cos theta|                     (Eq. 1, 8-9)

<L_nee> one emitter sample (next-event estimation, no MIS weight: the sampled
directions below never count emission they hit), L_ind(x, w) the radiance leaving
the point y that w hits, without y's emission: a path traced from x along w
(Mitsuba's ``path`` with one segment less than ``max_depth``) estimates L_i(x, w),
whose first term is y's emission L_e(y) with weight 1, and L_e(y), evaluated at the
same hit, is subtracted (``path``'s ``hide_emitters`` would not do: it ends the
path where its first hit is an emitter, dropping that emitter's reflected light), and g_p a
per-pixel model of f (BSDF and cosine included, as the paper's SH and vMF control
variates are), fitted from earlier frames: an SH expansion (renderers.caches.sh)
or a vMF mixture (renderers.caches.vmf). So L has the expectation of ``path`` at
``max_depth``, whatever g is.

The domain. g and G live on the whole sphere (their closed forms are over S^2),
while BSDF sampling has q = 0 below the surface, where g is not 0: G with
BSDF-sampled residuals would miss -int_{q=0} g. So w is drawn from a one-sample
mixture of uniform sphere sampling (probability ``uniform_fraction`` = a) and
sampling the BSDF's smooth lobes (1 - a), and every sample is divided by the
mixture density

    q(w) = a / (4 pi) + (1 - a) p_bsdf(w)  >=  a / (4 pi)  >  0 on S^2.

A BSDF sample that fails (p_bsdf = 0) contributes 0: the density of the
directions actually produced is q, with the failed mass lost, so
E[(f - g)/q; produced] = int_S2 (f - g). Delta lobes are neither sampled nor
evaluated (the method refuses scenes with delta BSDFs).

Fitting: the render keeps each sample's w, f(w) / q(w) and q(w) (0 where no direction
was produced; renderers.integrators.control_variate_records); the model is fitted
from them only between frames (``fit``), so a frame's g never depends on its own
samples.
"""

from __future__ import annotations

from typing import Protocol

import drjit as dr
import mitsuba as mi

from renderers.integrators import register
from renderers.integrators.cached import pixel_index, smooth_context
from renderers.integrators.control_variate_records import SampleRecords

PLUGIN_NAME = "nirc_control_variate"


class DirectionalModel(Protocol):
    """A per-pixel model g_p(w) of the shading integrand with a closed-form integral."""

    def eval(self, pixel: mi.UInt32, w: mi.Vector3f, active: mi.Bool) -> mi.Spectrum:
        """g_p(w), w a world-space unit direction."""
        ...

    def integral(self, pixel: mi.UInt32, active: mi.Bool) -> mi.Spectrum:
        """G_p = int_S2 g_p(w) dw, in closed form."""
        ...

    def fit(self, records: SampleRecords) -> None:
        """Fold one render's samples into the model (between frames)."""
        ...


def mixture_pdf(uniform_fraction: float, bsdf_pdf: mi.Float) -> mi.Float:
    """q(w) = a / (4 pi) + (1 - a) p_bsdf(w) (module docstring)."""
    return uniform_fraction * dr.inv_four_pi + (1.0 - uniform_fraction) * bsdf_pdf


@register
class ControlVariateIntegrator(mi.SamplingIntegrator):
    """L = L_e(x) + <L_nee(x)> + G_p + (f(w) - g_p(w)) / q(w) at the first hit x (module
    docstring).

    Properties: ``max_depth`` (-1 or >= 2, as Mitsuba's ``path``), ``uniform_fraction``
    (a in (0, 1]). The model must be set on the loaded instance (:meth:`with_model`);
    ``fitting`` says whether a render keeps its samples (:attr:`records`) for the
    model's next fit.
    """
    plugin_name = PLUGIN_NAME

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.max_depth = int(props.get("max_depth", -1))
        self.uniform_fraction = float(props.get("uniform_fraction", 0.25))
        if self.max_depth == 0 or self.max_depth == 1 or self.max_depth < -1:
            raise ValueError("max_depth must be -1 (unbounded) or >= 2")
        if not 0.0 < self.uniform_fraction <= 1.0:
            raise ValueError("uniform_fraction must be in (0, 1]: q must cover the sphere")
        self.incident = mi.load_dict({"type": "path", "max_depth": max(self.max_depth - 1, -1)})
        self.model: DirectionalModel | None = None
        self.fitting = True
        self.records: SampleRecords | None = None   # of the last render, while fitting

    def with_model(self, model: DirectionalModel) -> ControlVariateIntegrator:
        self.model = model
        return self

    def aov_names(self) -> list[str]:
        return ["depth"]

    def sample_direction(self, si: mi.SurfaceInteraction3f, bsdf: mi.BSDF, sampler: mi.Sampler,
                         active: mi.Bool) -> tuple[mi.Vector3f, mi.Spectrum, mi.Float, mi.Bool]:
        """(w local, f_s cos at w, q(w), produced): one sample of the mixture."""
        ctx = smooth_context()
        uniform = sampler.next_1d(active) < self.uniform_fraction
        u1, u2 = sampler.next_1d(active), sampler.next_2d(active)
        bs, _ = bsdf.sample(ctx, si, u1, u2, active & ~uniform)
        w_local = dr.select(uniform, mi.warp.square_to_uniform_sphere(u2), bs.wo)
        produced = active & (uniform | (bs.pdf > 0))
        f_cos, bsdf_pdf = bsdf.eval_pdf(ctx, si, w_local, produced)
        return w_local, f_cos, mixture_pdf(self.uniform_fraction, bsdf_pdf), produced

    def next_event(self, scene: mi.Scene, si: mi.SurfaceInteraction3f, bsdf: mi.BSDF,
                   sampler: mi.Sampler, active: mi.Bool) -> mi.Spectrum:
        """<L_nee(x)>: one emitter sample, shadow ray included, f_s cos L_e / p_light."""
        ds, emitted = scene.sample_emitter_direction(si, sampler.next_2d(active), True, active)
        seen = active & (ds.pdf != 0)
        f_cos = bsdf.eval(smooth_context(), si, si.to_local(ds.d), seen)
        return dr.select(seen, f_cos * emitted, 0.0)

    def indirect(self, scene: mi.Scene, sampler: mi.Sampler, si: mi.SurfaceInteraction3f,
                 w: mi.Vector3f, active: mi.Bool) -> mi.Spectrum:
        """<L_ind(x, w)>: one path traced from x along the world direction w, without the
        emission of the point y it hits (module docstring)."""
        # L_ind = L_i - L_e(y): NEE at x counts the emission the direction reaches.
        toward = si.spawn_ray(w)
        y = scene.ray_intersect(toward, active)
        L_i, _, _ = self.incident.sample(scene, sampler, toward, None, active)
        return L_i - y.emitter(scene, active).eval(y, active)

    def sample(self, scene: mi.Scene, sampler: mi.Sampler, ray: mi.RayDifferential3f,
               medium: mi.Medium = None,
               active: mi.Bool = True) -> tuple[mi.Spectrum, mi.Bool, list[mi.Float]]:
        if self.model is None:
            raise ValueError("ControlVariateIntegrator needs a model: call with_model first")
        si = scene.ray_intersect(mi.Ray3f(ray), active)
        hit = active & si.is_valid()
        # si.emitter() is the environment (or none) where the ray missed.
        L = mi.Spectrum(si.emitter(scene, active).eval(si, active))
        pixel = pixel_index(ray, sampler)
        bsdf = si.bsdf(ray)
        L += self.next_event(scene, si, bsdf, sampler, hit)

        w_local, f_cos, q, produced = self.sample_direction(si, bsdf, sampler, hit)
        w = si.to_world(w_local)
        lit = produced & (dr.max(mi.unpolarized_spectrum(f_cos)) > 0)
        f = dr.select(lit, f_cos * self.indirect(scene, sampler, si, w, lit), 0.0)
        g = self.model.eval(pixel, w, produced)
        # Eq. 7: G + (f - g) / q; a direction not produced adds no residual.
        residual = dr.select(produced, (f - g) / q, 0.0)
        L += dr.select(hit, self.model.integral(pixel, hit) + residual, 0.0)
        if self.fitting:
            self.records = SampleRecords.write(w, dr.select(produced, f / q, 0.0),
                                               dr.select(produced, q, 0.0), hit,
                                               sampler.sample_count())
        valid = hit | (active & (scene.environment() is not None))
        return L, valid, [dr.select(hit, 1.0, 0.0)]
