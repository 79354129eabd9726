"""What `neural-di` and `nrc-di` share: direct light at primary hits from a cache
trained online on points of the scene, and what they need of a scene.

Both are the visibility cache's frame loop
(renderers.methods.nvc_lights.visibility_cache_render: pre-train, then one
training step and one render per frame) around an integrator of the first
hits' direct light (renderers.integrators.primary), so their reference is
Mitsuba's ``path`` at max_depth 2 (as `restir-di`'s).

==================  ========  =====================================================
parameter           default   meaning
==================  ========  =====================================================
max_depth           2         fixed: direct light at primary hits (the reference's
                              depth)
world_points        4096      training points per frame from the scene's box
                              (visibility paper Sec. 3.3)
camera_points       4096      training points per frame at first hits of random
                              camera rays (visibility paper Sec. 3.3)
pretrain_frames     0         training frames before the first (warm-up) frame
cache               {}        overrides of the method's cache preset
==================  ========  =====================================================
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from renderers.methods.base import MethodParams


class PrimaryCacheParams(MethodParams):
    """The training of a primary-hit cache (module docstring)."""

    max_depth: Literal[2] = Field(2, description="fixed: direct light at primary hits")
    world_points: int = Field(4096, ge=0, le=1 << 20,
                              description="training points per frame from the scene's box")
    camera_points: int = Field(4096, ge=0, le=1 << 20,
                               description="training points per frame at camera first hits")
    pretrain_frames: int = Field(0, ge=0, le=100_000,
                                 description="training frames before the first (warm-up) frame")
    cache: dict[str, Any] = Field(default_factory=dict, description="cache config overrides")


def lit_surface(features: Any) -> tuple[bool, str]:
    """A surface to shade and at least one emitter."""
    if features.shape_count == 0:
        return False, "the scene has no surface to shade"
    if features.emitter_count == 0:
        return False, "no emitter"
    return True, ""
