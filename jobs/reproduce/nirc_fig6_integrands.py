"""[DKHD24] Fig. 6's integrand images: at the first hit x of a few pixels, the shading
integrand over the sphere of directions and each model's fit of it, as latitude-longitude
images (integrands.png beside the figure).

The integrand the control variates fit (NIRC Eq. 1, 8-9; renderers.integrators.
control_variate) at x, seen along the camera ray through the pixel's centre (w_o), is

    f(w) = L_ind(x, w) f_s(x, w, w_o) |cos theta|,

L_ind the radiance leaving the point y that w hits, without y's emission (next-event
estimation at x counts it). The reference estimates it per direction as the mean of
``spp`` paths traced from x along w (the estimator's own :meth:`indirect`, Mitsuba's
``path`` one segment shorter than ``max_depth``), times f_s cos evaluated exactly. Each
model's g after the figure's F training frames (1 spp each, as
jobs/reproduce/nirc_fig6_curves.py trains them), evaluated by the model itself:

* SH, vMF, NCV: ``model.eval(pixel, w)`` (renderers.caches.sh, vmf, ncv: for NCV G q(w));
* NIRC: its cache's incident radiance n(x, w) (``cache.query`` on the cache inputs of x,
  as the deferred pass queries it) times f_s cos, the term n f_s cos of Eq. 11.

The grid: :data:`GRID` cells of directions in the shading frame of x, each cell's centre
w(theta, phi) = (sin theta cos phi, sin theta sin phi, cos theta), theta from the shading
normal (rows, top: theta = 0, so the upper half of an image is the hemisphere above the
surface, where f lives; the models are fitted on the whole sphere) and phi from the frame's
tangent (columns). Shown is the channel mean.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

SCENE = "cornell-box"
#: The pixels (column, row) as fractions of the image size: three different surfaces
#: (at 16x16 pixels (3, 8), (8, 14) and (11, 6)).
PIXEL_FRACTIONS = ((0.19, 0.5), (0.5, 0.88), (0.69, 0.38))
#: (columns over phi, rows over theta) of an image.
GRID = (64, 32)
#: The models drawn, by the figure's series label: the control-variate methods and NIRC.
CONTROL_VARIATES = {"SH": "cv-sh", "vMF": "cv-vmf", "NCV": "ncv"}
CACHE_LABEL = "NIRC"
REFERENCE = "reference"


@dataclass(frozen=True)
class Integrands:
    """The images: ``values[p, c]`` (GRID rows x columns) of pixel ``pixels[p]`` and
    column ``columns[c]`` (the reference first)."""

    scene: str
    pixels: list[tuple[int, int]]
    columns: list[str]
    values: np.ndarray
    spp: int
    frames: int


def grid_directions(columns: int, rows: int) -> np.ndarray:
    """The cells' centre directions in the shading frame, shape (rows, columns, 3)
    (module docstring)."""
    theta = (np.arange(rows) + 0.5) * math.pi / rows
    phi = (np.arange(columns) + 0.5) * 2.0 * math.pi / columns
    t, p = np.meshgrid(theta, phi, indexing="ij")
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def image_pixels(resolution: int) -> list[tuple[int, int]]:
    """:data:`PIXEL_FRACTIONS` at a square image of ``resolution`` pixels a side."""
    return [(min(int(fx * resolution), resolution - 1), min(int(fy * resolution),
                                                             resolution - 1))
            for fx, fy in PIXEL_FRACTIONS]


class GridHits:
    """The first hits of ``pixels`` repeated for every grid direction (``repeat`` lanes
    each): lane ``(p * D + d) * repeat + r`` is pixel p, direction d."""

    def __init__(self, scene: Any, pixels: list[tuple[int, int]], grid: tuple[int, int],
                 repeat: int = 1) -> None:
        import drjit as dr
        import mitsuba as mi

        from renderers.caches.ncv import centre_rays

        width = int(scene.sensors()[0].film().crop_size()[0])
        local = grid_directions(*grid).reshape(-1, 3)
        self.directions, self.repeat = len(local), repeat
        cell = dr.arange(mi.UInt32, len(pixels) * self.directions * repeat) // repeat
        image_index = mi.UInt32([row * width + column for column, row in pixels])
        self.pixel = dr.gather(mi.UInt32, image_index, cell // self.directions)
        self.si = scene.ray_intersect(centre_rays(scene, self.pixel))
        self.hit = self.si.is_valid()
        self.bsdf = self.si.bsdf()
        table = mi.Vector3f(*(mi.Float(np.ascontiguousarray(axis, dtype=np.float32))
                              for axis in local.T))
        self.w_local = dr.gather(mi.Vector3f, table, cell % self.directions)
        self.w = self.si.to_world(self.w_local)

    def bsdf_cos(self) -> Any:
        """f_s(x, w, w_o) |cos theta| (smooth lobes; 0 below the surface)."""
        from renderers.integrators.cached import smooth_context

        return self.bsdf.eval(smooth_context(), self.si, self.w_local, self.hit)

    def images(self, value: Any, pixels: int, grid: tuple[int, int]) -> np.ndarray:
        """The channel mean of a Spectrum per lane, averaged over the repeats, as
        (pixels, rows, columns) images."""
        mean = np.asarray(value).reshape(3, -1).mean(axis=0)
        return mean.reshape(pixels, grid[1], grid[0], self.repeat).mean(axis=-1)


def reference_images(scene: Any, pixels: list[tuple[int, int]], spp: int, max_depth: int,
                     seed: int, grid: tuple[int, int] = GRID) -> np.ndarray:
    """f(w) per grid cell: ``spp`` paths a direction (module docstring)."""
    import drjit as dr
    import mitsuba as mi

    from renderers.integrators import control_variate, register_plugins

    register_plugins()
    estimator = mi.load_dict({"type": control_variate.PLUGIN_NAME, "max_depth": max_depth})
    hits = GridHits(scene, pixels, grid, repeat=spp)
    f_cos = hits.bsdf_cos()
    lit = hits.hit & (dr.max(mi.unpolarized_spectrum(f_cos)) > 0)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, dr.width(hits.pixel))
    f = dr.select(lit, f_cos * estimator.indirect(scene, sampler, hits.si, hits.w, lit), 0.0)
    return hits.images(f, len(pixels), grid)


def model_images(scene: Any, pixels: list[tuple[int, int]], model: Any,
                 grid: tuple[int, int] = GRID) -> np.ndarray:
    """A control variate's g_p(w) per grid cell (renderers.integrators.control_variate's
    DirectionalModel.eval)."""
    hits = GridHits(scene, pixels, grid)
    return hits.images(model.eval(hits.pixel, hits.w, hits.hit), len(pixels), grid)


def cache_images(scene: Any, pixels: list[tuple[int, int]], integrator: Any, cache: Any,
                 grid: tuple[int, int] = GRID) -> np.ndarray:
    """NIRC's n(x, w) f_s cos per grid cell: the cache queried on the inputs of x."""
    import drjit as dr
    import mitsuba as mi

    hits = GridHits(scene, pixels, grid)
    surface = cache.surface_features(**integrator.surface_inputs(hits.si, hits.bsdf))
    n = mi.Spectrum(cache.query(surface, hits.w))
    return hits.images(dr.select(hits.hit, n * hits.bsdf_cos(), 0.0), len(pixels), grid)


def model_factory(method: str) -> Any:
    """The per-pixel model factory of a control-variate method (renderers.methods)."""
    from renderers.methods import cv_sh, cv_vmf, ncv

    return {"cv-sh": cv_sh.sh_model, "cv-vmf": cv_vmf.vmf_model, "ncv": ncv.ncv_model}[method]


def measure_integrands(ctx: Any, series: dict[str, dict[str, Any]]) -> Integrands:
    """The reference and each model of ``series`` (label -> the figure's method
    parameters; :data:`CONTROL_VARIATES` and :data:`CACHE_LABEL`) after the budget's F
    frames, at :func:`image_pixels` of :data:`SCENE`; the reference with the budget's
    reference spp a direction."""
    from jobs.protocol.scene_store import load_spec_scene
    from jobs.reproduce import nirc_fig6_curves as curves
    from renderers.methods import parse_params
    from renderers.seeding import derive_seed

    b = ctx.budget
    scene = load_spec_scene(SCENE, b.resolution, ctx.settings)
    pixels = image_pixels(b.resolution)
    columns, images = [REFERENCE], []
    for label, method in CONTROL_VARIATES.items():
        params = parse_params(method, series[label])
        if ctx.progress:
            ctx.progress(f"{label} integrand on {SCENE}", 0, b.frames)
        model = curves.model_frames(model_factory(method), scene, params,
                                    ("fig6 integrand", SCENE, method), b.frames, None)
        columns.append(label)
        images.append(model_images(scene.scene, pixels, model))
    integrator, cache = curves.nirc_frames(scene, parse_params("nirc", series[CACHE_LABEL]),
                                           ("fig6 integrand", SCENE, "nirc"), b.frames, None)
    columns.append(CACHE_LABEL)
    images.append(cache_images(scene.scene, pixels, integrator, cache))
    max_depth = parse_params(CONTROL_VARIATES["SH"], series["SH"]).max_depth
    reference = reference_images(scene.scene, pixels, b.ref_spp, max_depth,
                                 derive_seed("fig6 integrand", SCENE, "reference"))
    values = np.stack([reference, *images], axis=1)
    return Integrands(SCENE, pixels, columns, values, b.ref_spp, b.frames)


def draw_integrands(integrands: Integrands, path: Path) -> Path:
    """One row per pixel, one column per image; a symmetric log colour scale per row
    (linear within 1 % of its maximum), its maximum the reference's largest |f|,
    models clipped there (SH and NCV can be negative: blue)."""
    from matplotlib.colors import SymLogNorm

    from jobs.views.plots import new_figure, save_png

    rows, columns = integrands.values.shape[:2]
    figure, axes = new_figure(rows, columns, f"[DKHD24] Fig. 6: integrand f = L_ind f_s cos "
                              f"at the first hit ({integrands.scene}; reference "
                              f"{integrands.spp} spp a direction; models after "
                              f"{integrands.frames} frames)",
                              figsize=(2.6 * columns + 1.0, 1.6 * rows + 1.2))
    for p, (column, row) in enumerate(integrands.pixels):
        peak = float(np.nanmax(np.abs(integrands.values[p, 0]))) or 1.0
        norm = SymLogNorm(linthresh=0.01 * peak, vmin=-peak, vmax=peak)
        for c, label in enumerate(integrands.columns):
            ax = axes[p * columns + c]
            shown = ax.imshow(integrands.values[p, c], cmap="RdBu_r", norm=norm,
                              extent=(0.0, 360.0, 180.0, 0.0), aspect="auto")
            ax.set_title(f"{label}, pixel ({column}, {row})", fontsize=8)
            ax.set_xlabel("phi (deg)", fontsize=7)
            ax.set_ylabel("theta from the normal (deg)", fontsize=7)
            ax.tick_params(labelsize=6)
        figure.colorbar(shown, ax=axes[p * columns + columns - 1])
    return save_png(figure, path)
