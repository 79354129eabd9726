"""`restir-di`: screen-space ReSTIR DI at primary hits, the Neural Visibility Cache
paper's baseline (Sec. 4.1: 8 initial candidates, a shadow ray for the selected
one, temporal reuse clamped at 20x the new reservoir's confidence, spatial
reuse within 32 px).

Direct light at the camera rays' first hits only: a frame is the emission the
camera sees plus the direct light of every pixel's first hit, the quantity of
Mitsuba's ``path`` at max_depth 2 (no indirect light; the paper compares at
primary hits too). One sample (and one reservoir) per pixel and frame; ``spp``
renders that many independent reservoir chains per pixel and averages them.
The estimator (renderers.integrators.restir; docs/estimators.md, "restir-di")
is unbiased with and without reuse: pairwise MIS (the pixel's own reservoir as
the canonical input) over the reused reservoirs with visibility-checked
targets, not the biased 1/M normalisation; the light that a
delta lobe (a mirror, smooth plastic's coating) reflects at the first hit, which
no light sample can carry, comes from one BSDF sample per pixel.

==================  ========  =====================================================
parameter           default   meaning
==================  ========  =====================================================
max_depth           2         fixed: direct light at primary hits (the reference's
                              depth)
candidates          8         initial light samples per pixel and frame, drawn by
                              power (pt-power's selection) x uniform on the light's
                              area (paper Sec. 4.1: 8)
temporal            true      reuse the previous frame's reservoir where the pixel's
                              first hit was seen (static camera: the same pixel; a
                              moved camera: along motion vectors, rejected on a
                              normal or depth change; after a change of the
                              emitters or shapes: none)
m_clamp             20        the previous reservoir's confidence M is clamped to
                              m_clamp x candidates (paper Sec. 4.1: 20x)
spatial             true      reuse reservoirs of neighbouring pixels
spatial_neighbours  3         neighbours per pixel, uniform in the disk
spatial_radius      32        of this radius in pixels (paper Sec. 4.1: 32 px)
==================  ========  =====================================================

Shadow rays per pixel and frame: 1 (the candidate's), plus 2 for temporal
reuse and 2 k for spatial reuse with k neighbours (the pairwise MIS weights'
visibility: from the pixel toward each neighbour's sample and from each
neighbour toward the pixel's sample), 9 with the defaults (15 up to estimator
version 2, whose Talbot MIS cast (k+1) k for spatial reuse). Applies to scenes
whose emitters are all area emitters (a light sample is a point on a surface);
environment and delta emitters are not supported and such scenes are skipped
with the reason.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal

from pydantic import Field

from renderers.methods import register
from renderers.methods.base import FrameHooks, Knob, Method, MethodParams, RenderOutput, run_frames
from renderers.methods.pt import SPP_CANDIDATES
from renderers.seeding import derive_seed
from renderers.timing import StageTimer, synchronize

#: What runs before a frame's reservoirs (``(index, seed, timer)``; e.g. a cache's training).
BeforeFrame = Callable[[int, int, StageTimer], None]


class ReSTIRDIParams(MethodParams):
    """The reservoirs' parameters (module docstring)."""

    max_depth: Literal[2] = Field(2, description="fixed: direct light at primary hits")
    candidates: int = Field(8, ge=1, le=64, description="initial candidates per pixel")
    temporal: bool = Field(True, description="reuse the previous frame's reservoir")
    m_clamp: float = Field(20.0, gt=0.0, le=1000.0,
                           description="previous confidence clamped to m_clamp x candidates")
    spatial: bool = Field(True, description="reuse neighbouring pixels' reservoirs")
    spatial_neighbours: int = Field(3, ge=1, le=16, description="neighbours per pixel")
    spatial_radius: float = Field(32.0, gt=0.0, le=1024.0, description="in pixels")


def render(scene: Any, params: ReSTIRDIParams, *, seed_parts: tuple[Any, ...], spp: int,
           frames: int, hooks: FrameHooks = FrameHooks()) -> RenderOutput:
    """The frame loop with the reservoirs of ``spp`` chains per pixel carried across frames.

    The warm-up renders two frames (compiling the kernels of a frame without and with
    history); its reservoirs are dropped, so timed frame 0 starts without history."""
    from renderers.integrators.restir import ReSTIRDI, check_scene

    check_scene(scene.scene)
    output = run_frames(ReSTIRFrame(ReSTIRDI(scene.scene, params, replicas=spp)),
                        seed_parts=seed_parts, frames=frames, spp=spp, hooks=hooks)
    output.method_stats = {"shadow_rays_per_sample": shadow_rays(params)}
    return output


class ReSTIRFrame:
    """``run_frames``' frame of a ``ReSTIRDI`` estimator, after ``before`` (if any): the
    mean over its replicas, on the device. A warm-up frame renders a frame without
    history and one with; the further warm-up calls of a frozen estimator
    (:meth:`settle`) skip ``before``, so a cache trains once in the warm-up."""

    def __init__(self, restir: Any, before: BeforeFrame | None = None,
                 cache: Any = None) -> None:
        self.restir, self.before = restir, before
        # A cache ``before`` trains, whose frozen step settles in the warm-up too.
        self.cache = cache if cache is not None and cache.recordings() is not None else None
        if restir.recordings() is not None:
            self.recordings = lambda: restir.recordings() + (
                self.cache.recordings() if self.cache is not None else 0)

    def __call__(self, index: int, seed: int, timer: StageTimer) -> Any:
        if self.before is not None:
            self.before(index, seed, timer)
        return self.settle(index, seed, timer)

    def settle(self, index: int, seed: int, timer: StageTimer) -> Any:
        """The frame without ``before`` (and a settling call of the cache's step)."""
        import drjit as dr

        if self.cache is not None and index < 0:
            self.cache.settle()
        if index <= 0:
            self.restir.reset()
        if index < 0:
            self.restir.render(derive_seed(seed, "history"))
        with timer.stage("render"):
            image = dr.mean(self.restir.render(seed), axis=0)
            synchronize(image)
        return image


def shadow_rays(params: ReSTIRDIParams) -> int:
    """Shadow rays per pixel sample and frame once reuse runs (module docstring)."""
    spatial = 2 * params.spatial_neighbours if params.spatial else 0
    return 1 + 2 * params.temporal + spatial


def applies(features: Any) -> tuple[bool, str]:
    """A surface, and only area emitters (at least one)."""
    if features.shape_count == 0:
        return False, "the scene has no surface to shade"
    if features.emitter_count == 0:
        return False, "no emitter"
    if features.area_emitter_count < features.emitter_count:
        kind = "an environment emitter" if features.has_envmap else "a delta emitter"
        return False, f"{kind}: restir-di samples points on area emitters only"
    return True, ""


METHOD = register(Method("restir-di",
                "screen-space ReSTIR DI (8 candidates, temporal + spatial reuse, unbiased "
                "pairwise MIS): direct light at primary hits only (max_depth 2)",
                ReSTIRDIParams, render, version=4, requires=applies, label="ReSTIR DI",
                knob=Knob("spp", SPP_CANDIDATES), unbiased=True,
                correlated_pixels=True, correlated_frames=True))
