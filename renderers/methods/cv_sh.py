"""`cv-sh`: a per-pixel spherical-harmonics control variate at the first hits.

NIRC paper Sec. 6.1 (Fig. 6): the shading integrand at each pixel's first hit
(incident radiance x BSDF x cosine) is modelled by ``sh.bands`` bands of real SH
per colour channel (5 bands: 25 coefficients, 75 floats per pixel, the paper's
equal-memory preset), fitted by projection from the earlier frames' samples
(renderers.caches.sh), and used as a control variate with its closed-form
integral (Eq. 7; renderers.integrators.control_variate). Unbiased whatever the
fit. Parameters: those of renderers.methods.cv_frames and ``sh`` (overrides of
renderers.caches.sh.SHConfig, e.g. ``{"bands": 3}``).
"""

from __future__ import annotations

from typing import Any

from pydantic import Field

from renderers.methods.cv_frames import ControlVariateParams, control_variate_method, film_pixels


class CVSHParams(ControlVariateParams):
    """The control-variate estimator's parameters and the SH model's overrides."""

    sh: dict[str, Any] = Field(default_factory=dict,
                               description="SH model overrides (renderers.caches.sh.SHConfig)")

    def cache_presets(self) -> dict[str, Any]:
        from renderers.caches.sh import sh_config

        return {"sh": sh_config}


def sh_model(params: CVSHParams, scene: Any, _seed_parts: tuple[Any, ...]) -> Any:
    """The per-pixel SH model of the scene's pixels, zero (g = 0) until the first fit."""
    from renderers.caches.sh import SHModel

    return SHModel(params.cache_config("sh"), film_pixels(scene))


METHOD = control_variate_method(
    "cv-sh", "per-pixel spherical-harmonics control variate of the first hits' shading "
             "integrand, closed-form integral (unbiased)",
    CVSHParams, sh_model, version=1, label="SH CV", unbiased=True)
