"""The registry of render methods (the ``method`` of a render job).

A method is one module of this package that declares everything about itself
at its bottom, as ``METHOD = Method(...)`` (renderers/methods/base.py): its
pydantic parameter model (validated once, so a bad value is a clear error
naming the field), its render function, the version of its estimator, its
integrators (registered per Mitsuba variant when a render starts), its
equal-time knob, its part in sweeps, its cache builder and what it needs of a
scene. ``jobs/`` and ``service/`` read this registry and never name a method;
adding one is a module plus one line in ``METHODS`` (docs/architecture.md).
Reading the registry does not import Mitsuba: the service validates specs
without it. Bump ``version`` whenever a change alters what the
method's images converge to or how noisy they are: stored results record it,
and results of another version are neither reused nor compared as equals
(version 1 is everything stored before versions were recorded).
"""

from __future__ import annotations

from typing import Any

from pydantic import ValidationError

from renderers.methods import (
    nirc,
    nrc,
    nvc_env,
    nvc_lights,
    pt,
    pt_power,
    pt_spatial,
    restir_di,
    restir_nvc,
)
from renderers.methods.base import Knob, Method, MethodParams, SweepRole

__all__ = ["BASELINE", "METHODS", "Knob", "Method", "MethodError", "MethodParams", "NotApplicable", "SweepRole",
           "check_applies", "equal_time_pairs", "get_method", "method_table", "parse_params", "sweep_methods", "sweep_series", "series_label"]


class MethodError(ValueError):
    """An unknown method or invalid method parameters (message names the field)."""


class NotApplicable(MethodError):
    """A method that cannot render a scene (its ``applies_to`` says why)."""


METHODS: dict[str, Method] = {module.METHOD.name: module.METHOD
                              for module in (pt, pt_power, pt_spatial, nvc_lights, nvc_env,
                                             restir_di, restir_nvc, nirc, nrc)}

#: The baseline: the method a time budget's ``pt_spp`` and a sweep's reference-sharing
#: base render name, and the one calibrated when nothing else is (unbiased path tracing).
BASELINE = pt.METHOD.name

#: Suffix of the series of a method calibrated to another's frame time in a sweep.
EQUAL_TIME_SUFFIX = "-equal-time"


def sweep_methods() -> tuple[str, ...]:
    """The methods an adaptive equal-bias sweep can run (those with a sweep role)."""
    return tuple(name for name, method in METHODS.items() if method.sweep is not None)


def sweep_series() -> list[str]:
    """Every series a sweep can have: each sweep method's, and its equal-time series."""
    names = []
    for name in sweep_methods():
        names.append(name)
        if METHODS[name].sweep.equal_time_against:
            names.append(name + EQUAL_TIME_SUFFIX)
    return names


def equal_time_pairs(methods: list[str] | tuple[str, ...]) -> list[tuple[str, str]]:
    """(method, budget method) of every equal-time series a sweep over ``methods`` has:
    the method's knob calibrated to the budget method's frame time (both swept)."""
    return [(name, METHODS[name].sweep.equal_time_against) for name in methods
            if name in METHODS and METHODS[name].sweep is not None
            and METHODS[name].sweep.equal_time_against in methods]


def series_label(series: str) -> str:
    """The label of a sweep series: a method's, or '<label> equal time'."""
    name = series.removesuffix(EQUAL_TIME_SUFFIX)
    method = METHODS.get(name)
    if method is None or method.sweep is None:
        return series
    return method.sweep.label + (" equal time" if series != name else "")


def get_method(name: str) -> Method:
    try:
        return METHODS[name]
    except KeyError:
        raise MethodError(
            f"unknown method '{name}'; available: {', '.join(sorted(METHODS))}"
        ) from None


def check_applies(method: str, features: Any) -> None:
    """Raise MethodError, in the user's terms, when ``method`` cannot render a scene
    with ``features`` (its ``applies_to``)."""
    applies, reason = get_method(method).applies_to(features)
    if not applies:
        raise NotApplicable(f"method '{method}' does not apply to this scene: {reason}")


def method_table() -> str:
    """The Markdown table of registered methods (README.md, "Methods"; checked by
    tests/renderers/test_registry.py; print it with ``python -m renderers.methods``)."""
    lines = ["| method | what it is | equal-time knob | in sweeps |",
             "|---|---|---|---|"]
    for name, method in METHODS.items():
        knob = f"`{method.knob.name}`" if method.knob else "—"
        sweep = method.sweep.label if method.sweep else "—"
        lines.append(f"| `{name}` | {method.description} | {knob} | {sweep} |")
    return "\n".join(lines)


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
