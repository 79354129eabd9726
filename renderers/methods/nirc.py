"""`nirc`: Neural Incident Radiance Cache, biased (Eq. 13) or unbiased (Eq. 10-12).

The estimators are in renderers/integrators/nirc.py; the frame loop with online
training in renderers/methods/cached.py.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, model_validator

from renderers.methods.cached import (
    CacheTrainingParams,
    cached_render,
    load_integrators,
    make_cache,
)


class NIRCParams(CacheTrainingParams):
    """Parameters of the `nirc` method (PT core and training parameters included)."""

    estimator: Literal["biased", "unbiased"] = "biased"
    termination: Literal["bth", "sph", "adaptive"] = Field(
        "bth", description="biased termination: BTH, SPH, or adaptive (v1 mask, then SPH)")
    nc: list[int] | None = Field(
        None, description="N_c: [4] biased; [N_c at v1, N_c later] adaptive; "
                          "per non-specular vertex, e.g. [3,1,1], unbiased")

    @model_validator(mode="after")
    def _check_nc(self) -> NIRCParams:
        nc = self.sample_counts()
        if any(n < 1 or n > 256 for n in nc):
            raise ValueError("nc entries must be in 1..256")
        if self.estimator == "biased" and self.termination == "adaptive":
            if len(nc) > 2:
                raise ValueError("adaptive termination takes N_c at v1 and later (e.g. nc=[8,1])")
        elif self.estimator == "biased" and len(nc) != 1:
            raise ValueError("the biased estimator takes one N_c (e.g. nc=[4])")
        if self.estimator == "unbiased" and len(nc) > 3:
            raise ValueError("the unbiased estimator takes at most 3 entries (one per vertex)")
        return self

    def sample_counts(self) -> list[int]:
        if self.nc is not None:
            return list(self.nc)
        if self.estimator == "unbiased":
            return [3, 1, 1]
        return [1] if self.termination == "adaptive" else [4]


def build(scene: Any, params: NIRCParams, seed: int) -> tuple[Any, Any, Any]:
    """(render integrator, training integrator, cache) of a NIRC render."""
    from renderers.caches import nirc_config
    from renderers.integrators import nirc

    integrator, trainer = load_integrators(
        nirc.NIRC_PLUGIN, nirc.NIRCIntegrator, params, key_vertex="departure",
        estimator=params.estimator, termination=params.termination,
        nc=",".join(str(n) for n in params.sample_counts()))
    return integrator, trainer, make_cache(scene, nirc_config, params, seed)


render = cached_render(build)
