"""The strongest PT, as the Pareto study renders it and the charts draw it.

Its candidates are the registry's methods whose parameters are exactly the path-tracing
core's (PT and its light selectors), each with :data:`STRONGEST_PT_PARAMS` on top of its
defaults; the strongest PT is their lower envelope at equal time (docs/pareto.md, "The
strongest PT"; jobs/views/envelope.py).
"""

from __future__ import annotations

from typing import Any

from jobs.protocol.labels import changed_params, run_label
from renderers.methods import METHODS
from renderers.methods.pt import PTParams

STRONGEST_PT_LABEL = "strongest PT"
#: What every candidate of the strongest PT sets on top of its method's defaults:
#: Russian roulette on the path throughput, as Mitsuba's ``path`` does.
STRONGEST_PT_PARAMS: dict[str, Any] = {"rr_mode": "throughput"}


def pt_core_methods() -> list[str]:
    """The candidates of the strongest PT: the registry's methods whose parameters are
    exactly the path-tracing core's (PT and its light selectors)."""
    return [name for name, method in METHODS.items()
            if set(method.params.model_fields) == set(PTParams.model_fields)]


def strongest_pt_of(method: str, params: dict[str, Any], leave_out: tuple[str, ...] = ()
                    ) -> str | None:
    """The strongest PT a run of ``method`` is a candidate of, by name: 'strongest PT',
    followed by the other values its label shows (less ``leave_out``: a chart's knobs),
    e.g. 'strongest PT (max_depth 4)'; None for a run that is no candidate."""
    if method not in pt_core_methods():
        return None
    changed = changed_params(method, params)
    if any(changed.get(name) != value for name, value in STRONGEST_PT_PARAMS.items()):
        return None
    label = run_label(method, params, leave_out=(*STRONGEST_PT_PARAMS, *leave_out))
    return STRONGEST_PT_LABEL + label.removeprefix(method)
