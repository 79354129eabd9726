"""`nirc`: Neural Incident Radiance Cache, biased (Eq. 13) or unbiased (Eq. 10-12).

The estimators are in renderers/integrators/nirc.py; the frame loop with online
training in renderers/methods/cached.py.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

from pydantic import Field, model_validator

from renderers.integrators.termination import get_policy, policy_names, termination_params_type
from renderers.methods import register
from renderers.methods.base import ComparisonRun, Knob, Method, SweepRole
from renderers.methods.cached import (
    ADAPTIVE_EQUAL_BIAS,
    CacheTrainingParams,
    TerminationChoice,
    cached_render,
    has_surface,
    load_integrators,
    make_cache,
    scale_training_floors,
    termination_params_field,
    training_stage_sizes,
)

#: The termination policies of NIRC's cache of incident radiance (the registry's).
IncidentTermination = Literal[policy_names("incident")]  # type: ignore[valid-type]
IncidentTerminationParams = termination_params_type("incident")


#: The training losses (NIRC paper Sec. 4.1) by parameter value, and the cache's
#: LossConfig.kind of each.
TrainingLoss = Literal["relative-l2", "l2", "variance"]
LOSS_KINDS = {"relative-l2": "relative_l2", "l2": "l2", "variance": "variance"}


class NIRCParams(CacheTrainingParams, TerminationChoice):
    """Parameters of the `nirc` method (PT core and training parameters included)."""

    #: The cache serves every non-specular vertex up to len(nc) (renderers.integrators.nirc).
    primary_only: ClassVar[bool] = False

    estimator: Literal["biased", "unbiased"] = Field(
        "biased", description="'biased': the cache's incident radiance at the termination "
                              "vertex (Eq. 13); 'unbiased': two-level Monte Carlo (Eq. 10-12)")
    termination: IncidentTermination = Field(
        "bth", description="biased termination policy (renderers/integrators/termination)")
    termination_params: IncidentTerminationParams = termination_params_field()
    nc: list[int] | None = Field(
        None, description="N_c: [4] biased; [N_c at v1, N_c later] adaptive; "
                          "per non-specular vertex, e.g. [3,1,1], unbiased")
    loss: TrainingLoss = Field(
        "relative-l2", description="training loss (NIRC paper Sec. 4.1): 'relative-l2' "
                                   "(Eq. 18), 'l2' (Eq. 17) or 'variance' (L_V, Eq. 16: F_r "
                                   "from cache.loss.group_size paths per first vertex; "
                                   "record_depth 1)")

    #: Stored, sent and hashed only when not the default: runs from before keep their keys.
    DUMPED_OFF_DEFAULT = ("loss",)

    @model_validator(mode="after")
    def _check_nc(self) -> NIRCParams:
        nc = self.sample_counts()
        if any(n < 1 or n > 256 for n in nc):
            raise ValueError("nc entries must be in 1..256")
        entries = get_policy(self.termination).nc_entries
        if self.estimator == "biased" and len(nc) > entries:
            raise ValueError(f"{self.termination} termination takes N_c at v1 and later "
                             "(e.g. nc=[8,1])" if entries > 1 else
                             "the biased estimator takes one N_c (e.g. nc=[4])")
        if self.estimator == "unbiased" and len(nc) > 3:
            raise ValueError("the unbiased estimator takes at most 3 entries (one per vertex)")
        if self.loss == "variance" and self.record_depth != 1:
            raise ValueError("loss 'variance' trains on the first vertex only, where a group "
                             "of training paths shares the shading point: set record_depth=1")
        return self

    def cache_presets(self) -> dict[str, Any]:
        from renderers.caches.config import nirc_config

        kind = LOSS_KINDS[self.loss]
        if kind == "relative_l2":
            return {"cache": nirc_config}   # the preset's own loss

        def with_loss(**overrides: Any) -> Any:
            chosen = overrides.get("loss", {}).get("kind", kind)
            if chosen != kind:
                raise ValueError(f"loss.kind {chosen!r} contradicts the parameter "
                                 f"loss={self.loss!r}")
            loss = {**overrides.get("loss", {}), "kind": kind}
            return nirc_config(**{**overrides, "loss": loss})

        return {"cache": with_loss}

    def sample_counts(self) -> list[int]:
        if self.nc is not None:
            return list(self.nc)
        if self.estimator == "unbiased":
            return [3, 1, 1]
        return list(get_policy(self.termination).default_nc)

    def resolved(self) -> dict[str, Any]:
        """The parameters with what ``nc = None`` stands for filled in (the estimator's or
        the termination policy's default N_c): how labels and stored runs show them."""
        return {**self.model_dump(mode="json"), "nc": self.sample_counts()}

    def termination_nc(self) -> tuple[int, int]:
        """N_c at v1 and at later vertices (the last entry), for the policy (BTH's Eq. 22)."""
        nc = self.sample_counts()
        return (nc[0], nc[-1])


def build(scene: Any, params: NIRCParams, seed: int) -> tuple[Any, Any, Any]:
    """(render integrator, training integrator, cache) of a NIRC render."""
    from renderers.integrators import nirc, register_plugins

    register_plugins()
    integrator, trainer = load_integrators(nirc.NIRC_PLUGIN, params, key_vertex="departure")
    return integrator, trainer, make_cache(scene, params.cache_config(), seed)


def with_nc_at_v1(params: dict[str, Any], value: int) -> dict[str, Any]:
    """``params`` with N_c ``value`` at the first vertex; the N_c of later vertices
    (adaptive termination: ``nc=[at v1, later]``) is kept."""
    later = list(params.get("nc") or [])[1:]
    return {**params, "nc": [value, *later]}


def _biased(params: dict[str, Any]) -> bool:
    return params.get("estimator", "biased") == "biased"


#: N_c candidates of equal-time calibration and of the 'NIRC equal time' sweep series.
NC_CANDIDATES = (1, 2, 4, 8, 16, 32)

METHOD = register(Method(
    "nirc", "Neural Incident Radiance Cache: biased (BTH/SPH termination) or unbiased "
            "two-level Monte Carlo",
    NIRCParams, cached_render(build), version=4,
    knob=Knob("nc", NC_CANDIDATES, apply=with_nc_at_v1, usable=_biased,
              requirement="biased nirc"),
    sweep=SweepRole("NIRC", ADAPTIVE_EQUAL_BIAS, point=lambda nc_v1: {"estimator": "biased", "nc": [nc_v1 or 1, 1]},
                    equal_time_against="nrc"),
    build=build, requires=has_surface, label="NIRC",
    stage_sizes=training_stage_sizes, scale_floors=scale_training_floors,
    comparison=(
        ComparisonRun(3, "NIRC biased", "NIRC biased (N_c 4)", {"estimator": "biased", "nc": [4]}),
        ComparisonRun(4, "NIRC unbiased", "NIRC unbiased (N_c 3,1,1)",
                      {"estimator": "unbiased", "nc": [3, 1, 1]}, role="matched"),
        ComparisonRun(5, "NIRC biased (equal time)", "NIRC biased (N_c {chosen})",
                      {"estimator": "biased"}, role="knob", unfit="over budget even at N_c = 1"),
    )))
