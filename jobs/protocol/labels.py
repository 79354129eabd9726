"""What defines a run, in a few words: its label, and its parameters as resolved.

One function, :func:`run_label`, names a run everywhere it is shown: ``runs list`` and
``runs show``, the REST API's ``method_label``, the dashboard, the charts' colours and
lines (jobs/views/chart_groups.py), the history over commits (jobs/ci/history.py,
where runs of different labels are never pooled) and exported summaries.

A label is the method followed by every resolved parameter that differs from the
method's defaults, resolved alike, and by the sweep threshold of a sweep point, e.g.
``nirc (adaptive, N_c 1,1, eps 0.3)``, ``pt (max_depth 4)``, ``grid-cache (var-bound,
termination_params {relative:False})``; a run at every default is labelled by its
method alone. *Resolved*: a parameter whose stored value stands for another (NIRC's
``nc = None``: the estimator's or the termination policy's default N_c) shows that
value, through the parameter model's optional ``resolved()`` method, so ``nc None``
and ``nc [4]`` of a BTH run are one configuration and one label.
"""

from __future__ import annotations

import json
from collections.abc import Collection
from functools import lru_cache
from typing import Any

from pydantic import ValidationError

from renderers.methods import METHODS

#: How parameters read in a label, in this order ('{}': the value); the other
#: parameters not at their default follow as 'name value', in the model's order.
SHOWN = {"estimator": "{}", "termination": "{}", "termination_params": "termination_params {}",
         "nc": "N_c {}", "eps": "eps {}"}


def _compact(value: Any) -> str:
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list):
        return ",".join(map(_compact, value))
    if isinstance(value, dict):
        return "{" + ",".join(f"{k}:{_compact(v)}" for k, v in value.items()) + "}"
    return str(value)


def _resolved_model(model: Any) -> dict[str, Any]:
    resolve = getattr(model, "resolved", None)
    return resolve() if callable(resolve) else model.model_dump(mode="json")


@lru_cache(maxsize=8192)
def _resolved(method: str, text: str) -> str:
    """:func:`resolved_params` of the JSON ``text`` (cached: lists of runs repeat them)."""
    params = json.loads(text)
    model = METHODS[method].params
    own = {name: value for name, value in params.items() if name in model.model_fields}
    try:
        values = _resolved_model(model.model_validate(own))
    except (ValidationError, ValueError, TypeError):
        return text    # stored by code whose parameters this one no longer takes: as stored
    return json.dumps({**params, **values})


def resolved_params(method: str, params: dict[str, Any]) -> dict[str, Any]:
    """A run's stored parameters with the method's values resolved (module docstring);
    keys that are not the method's (a sweep point's ``sweep``, a calibration) are kept.
    A method not registered here, or parameters its model refuses, are kept as stored."""
    if method not in METHODS:
        return dict(params)
    return json.loads(_resolved(method, json.dumps(params, sort_keys=True)))


@lru_cache(maxsize=256)
def _defaults(method: str) -> str:
    return json.dumps(_resolved_model(METHODS[method].params()))


def changed_params(method: str, params: dict[str, Any]) -> dict[str, Any]:
    """The resolved parameters of a run of ``method`` whose value is not the method's
    resolved default, in the model's order (none for a method not registered here)."""
    if method not in METHODS:
        return {}
    resolved, defaults = resolved_params(method, params), json.loads(_defaults(method))
    return {name: resolved[name] for name in METHODS[method].params.model_fields
            if name in resolved and resolved[name] != defaults.get(name)}


def defining_values(method: str, params: dict[str, Any]) -> dict[str, Any]:
    """What defines a run besides its method: :func:`changed_params` and, for a sweep
    point, its threshold ``eps``."""
    values = changed_params(method, params)
    eps = (params.get("sweep") or {}).get("eps")
    return {**values, "eps": eps} if eps is not None else values


def run_label(method: str, params: dict[str, Any], leave_out: Collection[str] = ()) -> str:
    """The run's label (module docstring): 'method (values that define it)', less the
    values named in ``leave_out`` (a chart's curve leaves out its knobs)."""
    values = {name: value for name, value in defining_values(method, params).items()
              if name not in leave_out}
    ordered = [name for name in SHOWN if name in values]
    ordered += [name for name in values if name not in SHOWN]
    parts = [SHOWN.get(name, f"{name} {{}}").format(_compact(values[name])) for name in ordered]
    return f"{method} ({', '.join(parts)})" if parts else method
