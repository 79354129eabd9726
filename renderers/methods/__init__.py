"""The registry of render methods (the ``method`` of a render job).

Each entry pairs a pydantic parameter model (validated, so a bad value is a
clear error naming the field) with the method's render function and the
version of its estimator. Bump ``version`` whenever a change alters what the
method's images converge to or how noisy they are: stored results record it,
and results of another version are neither reused nor compared as equals
(version 1 is everything stored before versions were recorded).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pydantic import ValidationError

from renderers.methods import nirc, nrc, pt, pt_power, pt_spatial
from renderers.methods.base import MethodParams, RenderOutput


class MethodError(ValueError):
    """An unknown method or invalid method parameters (message names the field)."""


@dataclass(frozen=True)
class Method:
    name: str
    description: str
    params: type[MethodParams]
    render: Callable[..., RenderOutput]
    version: int


METHODS: dict[str, Method] = {
    "pt": Method("pt", "unbiased path tracing: NEE + MIS + Russian roulette", pt.PTParams,
                 pt.render, version=2),
    "pt-power": Method("pt-power", "path tracing with emitters selected in proportion to power",
                       pt_power.PTPowerParams, pt_power.render, version=1),
    "pt-spatial": Method("pt-spatial", "path tracing with emitters selected by power / "
                         "distance^2 per shading point", pt_spatial.PTSpatialParams,
                         pt_spatial.render, version=1),
    "nirc": Method("nirc", "Neural Incident Radiance Cache: biased (BTH/SPH termination) or "
                   "unbiased two-level Monte Carlo", nirc.NIRCParams, nirc.render,
                   version=2),
    "nrc": Method("nrc", "Neural Radiance Cache, spread-angle termination", nrc.NRCParams,
                  nrc.render, version=2),
}


def get_method(name: str) -> Method:
    try:
        return METHODS[name]
    except KeyError:
        raise MethodError(
            f"unknown method '{name}'; available: {', '.join(sorted(METHODS))}"
        ) from None


def format_validation_error(err: ValidationError) -> str:
    """One line per bad field: 'max_depth: Input should be ... (got 0)'."""
    parts = []
    for item in err.errors():
        where = ".".join(str(p) for p in item["loc"]) or "parameters"
        parts.append(f"{where}: {item['msg']} (got {item.get('input')!r})")
    return "; ".join(parts)


def parse_params(method: str, values: dict[str, Any]) -> MethodParams:
    """Validate ``values`` against the method's parameter model."""
    model = get_method(method).params
    try:
        return model(**values)
    except ValidationError as err:
        raise MethodError(f"invalid {method} parameters: {format_validation_error(err)}") from None
