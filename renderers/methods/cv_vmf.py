"""`cv-vmf`: a per-pixel mixture of von Mises-Fisher lobes as control variate at the
first hits.

NIRC paper Sec. 6.1 (Fig. 6): the shading integrand at each pixel's first hit
(incident radiance x BSDF x cosine) is modelled by ``vmf.lobes`` vMF lobes of 7
coefficients (11 lobes: 77 floats per pixel, the paper's equal-memory preset),
their directions initialised on a spherical Fibonacci lattice and fitted by
stepwise EM with one batch per frame: the frame's spp samples of the pixel
(renderers.caches.vmf), and used as a control variate with its closed-form
integral (Eq. 7; renderers.integrators.control_variate): unbiased whatever the
fit. The M-step's kappa has a prior that keeps lobes fitted from a few samples
broad (renderers.caches.vmf). Parameters: those of renderers.methods.cv_frames
and ``vmf`` (overrides of renderers.caches.vmf.VMFConfig, e.g. ``{"lobes": 4}``).
"""

from __future__ import annotations

from typing import Any

from pydantic import Field

from renderers.methods.cv_frames import ControlVariateParams, control_variate_method, film_pixels


class CVVMFParams(ControlVariateParams):
    """The control-variate estimator's parameters and the vMF model's overrides."""

    vmf: dict[str, Any] = Field(default_factory=dict,
                                description="vMF model overrides (renderers.caches.vmf.VMFConfig)")

    def cache_presets(self) -> dict[str, Any]:
        from renderers.caches.vmf import vmf_config

        return {"vmf": vmf_config}


def vmf_model(params: CVVMFParams, scene: Any, _seed_parts: tuple[Any, ...]) -> Any:
    """The per-pixel vMF mixtures of the scene's pixels, zero (g = 0) until the first fit."""
    from renderers.caches.vmf import VMFModel

    return VMFModel(params.cache_config("vmf"), film_pixels(scene))


METHOD = control_variate_method(
    "cv-vmf", "per-pixel vMF-mixture control variate of the first hits' shading integrand "
              "(stepwise EM), closed-form integral (unbiased)",
    CVVMFParams, vmf_model, version=2, label="vMF CV", unbiased=True)
