"""Integrators of direct light at the camera rays' first hits only.

The quantity of Mitsuba's ``path`` at max_depth 2 (and of `restir-di`): per
camera ray, the emission L_e of the first hit x (or of the environment where
the ray leaves the scene) plus the direct light reflected at x toward the
camera, which a subclass supplies:

    L = L_e(x, ω_o) + D(x, ω_o)

`neural-di` and `nrc-di` differ only in D (renderers.integrators.neural_di,
renderers.integrators.nrc_di). The AOV ``depth`` is 1 where the ray hit a
surface (the frame loop's path statistics).
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi


class PrimaryHitIntegrator(mi.SamplingIntegrator):
    """L = L_e(x) + D(x) at the first hit x; subclasses implement :meth:`direct`."""

    def aov_names(self) -> list[str]:
        return ["depth"]

    # A frame is frozen (renderers.frozen) with the Dr.Jit data ``direct`` reads handed
    # over as an argument every frame: a cache's weights change with training.

    def frame_freezable(self) -> bool:
        return True

    def frame_state(self, scene: mi.Scene) -> dict[str, Any]:
        """The Dr.Jit data :meth:`direct` reads besides the scene (none here)."""
        return {}

    def bind_frame_state(self, scene: mi.Scene, state: dict[str, Any]) -> None:
        """Read :meth:`frame_state`'s data from ``state`` (a frozen frame's argument)."""

    def direct(self, scene: mi.Scene, sampler: mi.Sampler, si: mi.SurfaceInteraction3f,
               active: mi.Bool) -> mi.Color3f:
        """D(x, ω_o): the direct light reflected at ``si`` toward ``si.wi``."""
        raise NotImplementedError

    def sample(self, scene: mi.Scene, sampler: mi.Sampler, ray: mi.RayDifferential3f,
               medium: mi.Medium = None,
               active: mi.Bool = True) -> tuple[mi.Spectrum, mi.Bool, list[mi.Float]]:
        si = scene.ray_intersect(mi.Ray3f(ray), active)
        hit = active & si.is_valid()
        # si.emitter() is the environment (or none) where the ray missed.
        L = si.emitter(scene, active).eval(si, active)
        L += mi.Spectrum(self.direct(scene, sampler, si, hit))
        valid = hit | (active & (scene.environment() is not None))
        return L, valid, [dr.select(hit, 1.0, 0.0)]
