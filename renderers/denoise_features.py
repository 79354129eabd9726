"""The denoiser's auxiliary features of a scene: albedo and shading normal at the first hit.

Rendered once per run by Mitsuba's ``aov`` integrator at :data:`FEATURE_SPP` samples per
pixel with a fixed seed: the mean over a pixel's footprint, noise-free up to
anti-aliasing, as OIDN's ``cleanAux`` mode expects (metrics.denoised). Where the camera
ray leaves the scene both are 0.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from metrics.denoised import Features
from renderers.seeding import derive_seed

#: Samples per pixel of the feature images (a 64x64 Cornell box: ~0.2 s with the compile).
FEATURE_SPP = 64


def render_features(scene: Any, spp: int = FEATURE_SPP) -> Features:
    """Albedo (clamped to [0, 1], as OIDN reads it) and world-space shading normal of
    the Mitsuba ``scene`` at the first hit, through its sensor, at ``spp``."""
    import mitsuba as mi

    integrator = mi.load_dict({"type": "aov", "aovs": "albedo:albedo,normal:sh_normal"})
    image = np.asarray(mi.render(scene, integrator=integrator, spp=spp,
                                 seed=derive_seed("denoise-features")))
    if image.ndim != 3 or image.shape[2] != 6:
        raise RuntimeError(f"the aov integrator returned shape {image.shape}, not (H, W, 6)")
    albedo = np.clip(image[..., :3], 0.0, 1.0).astype(np.float32)
    normal = np.clip(image[..., 3:], -1.0, 1.0).astype(np.float32)
    return Features(albedo, normal)
