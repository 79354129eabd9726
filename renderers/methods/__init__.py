"""The registry of render methods (the ``method`` of a render job).

A method is one module of this package that declares everything about itself
at its bottom and registers, as ``METHOD = register(Method(...))``
(renderers/methods/base.py): its pydantic parameter model (validated once, so a
bad value is a clear error naming the field), its render function (which
registers the integrator plugins for the Mitsuba variant when a render starts,
renderers/integrators/__init__.py), the version of its estimator, its
equal-time knob, its part in sweeps, its cache builder and what it needs of a
scene. ``jobs/`` and ``service/`` read this registry and never name a method;
adding one is adding its module: the package imports every module in it
(renderers/registry.py; docs/architecture.md).
Reading the registry does not import Mitsuba: the service validates specs
without it. Bump ``version`` whenever a change alters what the
method's images converge to or how noisy they are: stored results record it,
and results of another version are neither reused nor compared as equals
(version 1 is everything stored before versions were recorded).

A package outside this repository adds methods through the entry-point group
``nirc_bench.methods`` (:data:`ENTRY_POINT_GROUP`): each entry point names a
``Method`` (``example-pt = my_package.methods:METHOD``) whose ``name`` is the
entry point's name. They are loaded with the registry and are then run like the
built-in ones; one that fails to load, is no ``Method``, or takes a name already
registered is left out, logged, and listed in :data:`SKIPPED_PLUGINS` with the
reason (docs/architecture.md, "A method from outside the repository").
"""

from __future__ import annotations

import logging
from importlib.metadata import entry_points
from typing import Any

from pydantic import ValidationError

from renderers.methods.base import Knob, Method, MethodParams, SweepRole
from renderers.registry import Registry, discover

__all__ = ["BASELINE", "BUILTIN", "ENTRY_POINT_GROUP", "METHODS", "METHOD_SOURCES", "SKIPPED_PLUGINS", "Knob", "Method", "MethodError", "MethodParams", "NotApplicable", "SweepRole",
           "check_applies", "equal_time_pairs", "get_method", "method_table", "parse_params", "sweep_methods", "sweep_series", "series_label"]


class MethodError(ValueError):
    """An unknown method or invalid method parameters (message names the field)."""


class NotApplicable(MethodError):
    """A method that cannot render a scene (its ``applies_to`` says why)."""


#: The methods of this repository, each registered by its own module
#: (``METHOD = register(Method(...))``), in the order the modules registered them.
BUILTIN: Registry[Method] = Registry("methods", lambda method: method.name)
register = BUILTIN.register
#: Modules of this package that are not imported with it: the caching frame in stages
#: imports Mitsuba (the frame loop imports it when such a frame renders).
NOT_DISCOVERED = ("staged",)
discover(__name__, __path__, skip=NOT_DISCOVERED)

#: The entry-point group other packages register methods under.
ENTRY_POINT_GROUP = "nirc_bench.methods"


def load_plugins(taken: dict[str, Method]) -> tuple[dict[str, Method], dict[str, str],
                                                    dict[str, str]]:
    """The methods of the entry-point group, the entry points left out
    (``'name = value'`` -> why) and, per loaded method, where it comes from.

    An entry point is left out, never fatal, when importing it raises, it is not a
    :class:`Method`, its ``Method.name`` differs from its own name, or the name is
    in ``taken`` (the built-ins win) or was loaded from another entry point first.
    """
    loaded: dict[str, Method] = {}
    skipped: dict[str, str] = {}
    sources: dict[str, str] = {}
    for point in entry_points(group=ENTRY_POINT_GROUP):
        where = f"{point.name} = {point.value}"
        try:
            method = point.load()
        except Exception as err:  # noqa: BLE001 - any error of foreign code skips it
            skipped[where] = f"could not be loaded: {type(err).__name__}: {err}"
            continue
        if not isinstance(method, Method):
            reason = f"it is a {type(method).__name__}, not a renderers.methods.Method"
        elif method.name != point.name:
            reason = f"it declares the method '{method.name}' under the name '{point.name}'"
        elif point.name in taken:
            reason = f"'{point.name}' is a built-in method's name"
        elif point.name in loaded:
            reason = f"'{point.name}' was registered by another entry point first"
        else:
            loaded[point.name] = method
            dist = point.dist
            sources[point.name] = (f"entry point {where}"
                                   + (f" ({dist.name} {dist.version})" if dist else ""))
            continue
        skipped[where] = reason
    for where, reason in skipped.items():
        logging.getLogger(__name__).warning("method entry point %s left out: %s", where, reason)
    return loaded, skipped, sources


_PLUGINS, SKIPPED_PLUGINS, _PLUGIN_SOURCES = load_plugins(BUILTIN)
#: Every method a spec may name: the built-ins, then those of other packages.
METHODS: dict[str, Method] = {**BUILTIN, **_PLUGINS}
#: Method name -> 'built-in' or the entry point (and package) it came from.
METHOD_SOURCES: dict[str, str] = {**dict.fromkeys(BUILTIN, "built-in"), **_PLUGIN_SOURCES}

#: The baseline: the method a time budget's ``pt_spp`` and a sweep's reference-sharing
#: base render name, and the one calibrated when nothing else is (unbiased path tracing).
BASELINE = "pt"

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
    """The Markdown table of the built-in methods (README.md, "Methods"; checked by
    tests/renderers/test_registry.py; print it with ``python -m renderers.methods``)."""
    lines = ["| method | what it is | equal-time knob | in sweeps |",
             "|---|---|---|---|"]
    for name, method in BUILTIN.items():
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
    """Validate ``values`` (JSON) against the method's parameter model, strictly, the one
    way parameters are validated: a string or a boolean is not a number."""
    model = get_method(method).params
    try:
        return model.model_validate(values, strict=True)
    except ValidationError as err:
        unknown = [str(item["loc"][0]) for item in err.errors()
                   if item["type"] == "extra_forbidden" and len(item["loc"]) == 1]
        valid = (f"; {method}'s parameters are {', '.join(model.model_fields)} (nirc-bench "
                 f"methods {method})" if unknown else "")
        raise MethodError(f"invalid {method} parameters: {format_validation_error(err)}"
                          f"{valid}") from None
