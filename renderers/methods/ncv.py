"""`ncv`: a neural control variate at the first hits [Müller et al. 2020], as the NIRC
paper compared it (Sec. 6.1, Fig. 6).

The control-variate estimator of renderers.integrators.control_variate (NIRC Eq. 7)
with g_p = G_p q_p: a normalizing flow q per colour channel (renderers.caches.flow)
and its integral G from a second network, both on the hash-grid and normal encoding
of the pixel's surface, trained online between frames on the frames' samples
(renderers.caches.ncv; docs/ncv.md). Unbiased whatever the training: G integrates g
exactly. Parameters: those of renderers.methods.cv_frames and

==================  ========  ====================================================
parameter           default   meaning
==================  ========  ====================================================
ncv                 {}        overrides of renderers.caches.ncv.NCVConfig, e.g.
                              ``{"flow": {"bins": 32}, "batch_size": 1024}``
==================  ========  ====================================================
"""

from __future__ import annotations

from typing import Any

from pydantic import Field

from renderers.methods.cv_frames import ControlVariateParams, control_variate_method
from renderers.seeding import derive_seed


class NCVParams(ControlVariateParams):
    """The control-variate estimator's parameters and the NCV model's overrides."""

    ncv: dict[str, Any] = Field(default_factory=dict,
                                description="NCV model overrides (renderers.caches.ncv.NCVConfig)")

    def cache_presets(self) -> dict[str, Any]:
        from renderers.caches.ncv import ncv_config

        return {"ncv": ncv_config}


def ncv_model(params: NCVParams, scene: Any, seed_parts: tuple[Any, ...]) -> Any:
    """The model on the scene's pixels' surfaces, networks initialised from the run's
    seed; G = 0 until the first fit."""
    from renderers.caches.ncv import NCVModel

    return NCVModel(params.cache_config("ncv"), scene.scene,
                    seed=derive_seed(*seed_parts, "ncv"))


METHOD = control_variate_method(
    "ncv", "neural control variate of the first hits' shading integrand: a normalizing "
           "flow per channel times a learned integral (unbiased)",
    NCVParams, ncv_model, version=2, label="NCV", unbiased=True)
