"""Which runs may share a chart, and which curve of it each run lies on.

Two runs are drawn on one error-vs-time chart or one Pareto front only when they
measured the same thing: the same scene, resolution and frames, the same protocol
(online training in the frame loop, or a frozen cache of a sweep point), the same
device (times compare on one device only), the same metric version and both current
(or both computed by older estimator versions). :func:`group_of` gives that key;
:func:`split_groups` cuts a list of runs by it.

A history over commits is drawn per :class:`Setting`: the same key less the versions,
which change along a history; a version change is a break of its series there, never
compared across (jobs/ci/history.py). Each series of a history chart is one run label
at one spp (:func:`history_series_label`): its point at a commit is a median, and a
median pools only runs of one label and spp.

What a method trades time for error with is no reason to split: spp, NIRC's N_c, the
termination policy's parameters and a sweep point's eps are each a position on the
method's curve, and the front is taken over all of them. So within a group every run
lies on the curve of :func:`curve_label` (its run label, jobs/protocol/labels.py, with
those knobs left out), ordered along it by :func:`knob_order`. The paper's PT (``pt``
at its defaults) and the strongest PT's candidates (``pt``, ``pt-power`` and
``pt-spatial`` with ``rr_mode throughput``, docs/pareto.md) are curves of the chart
like any other. Colours: jobs/views/chart_styles.py.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from jobs.protocol.labels import run_label
from renderers.methods import EQUAL_TIME_SUFFIX

ONLINE = "online training"
FROZEN = "frozen cache"
#: The values of a run label that are equal-time knobs: a position on a method's curve,
#: not a series (spp is a run's field and in no label).
KNOB_PARAMS = ("nc", "termination_params", "eps")


def protocol_of(params: Mapping[str, Any] | None) -> str:
    """A sweep point renders with a frozen, converged cache; every other run trains its
    cache online, inside the timed frames."""
    return FROZEN if params and "sweep" in params else ONLINE


@dataclass(frozen=True, order=True)
class Setting:
    """What runs compared over commits have in common: one history chart (the versions
    change along a history; a change is a break there, never compared across)."""

    scene: str
    width: int
    height: int
    frames: int
    protocol: str
    device: str

    @property
    def title(self) -> str:
        return (f"{self.scene}, {self.width}×{self.height}, {self.frames} "
                f"frame{'s' if self.frames != 1 else ''}, {self.protocol}, {self.device}")


@dataclass(frozen=True, order=True)
class Group(Setting):
    """What runs on one chart have in common: a setting, and the versions."""

    metric_version: int
    current: bool

    @property
    def title(self) -> str:
        versions = f"metrics v{self.metric_version}" + ("" if self.current else ", old versions")
        return f"{super().title}, {versions}"


def group_of(run: Mapping[str, Any]) -> Group:
    """The group of a run as the REST API lists it (jobs.protocol.results.RunResult)."""
    width, height = run["resolution"]
    return Group(run["scene"], width, height, run["frames"], protocol_of(run["params"]),
                 run["device_key"], run["metric_version"], bool(run["current"]))


def split_groups(runs: Iterable[Mapping[str, Any]]) -> dict[Group, list[Mapping[str, Any]]]:
    """The runs by group, groups in a stable order (largest resolution first)."""
    groups: dict[Group, list[Mapping[str, Any]]] = {}
    for run in runs:
        groups.setdefault(group_of(run), []).append(run)
    return dict(sorted(groups.items(), key=lambda item: (-item[0].width * item[0].height,
                                                          item[0])))


def history_series_label(label: str, spp: int) -> str:
    """The series of a history chart holding the runs of ``label`` at ``spp``."""
    return f"{label}, {spp} spp"


def _old(run: Mapping[str, Any], label: str) -> str:
    return label if run.get("current", True) else f"{label} [estimator v{run['estimator_version']}]"


def config_label(run: Mapping[str, Any]) -> str:
    """A run's method configuration: its method label, with its estimator version when
    that is not today's."""
    return _old(run, run.get("method_label") or run["method"])


def curve_label(run: Mapping[str, Any]) -> str:
    """The curve a run lies on: its run label without the equal-time knobs (module
    docstring); a sweep's equal-time series, whose N_c is calibrated per point, is a
    curve of its own."""
    params = run.get("params") or {}
    label = run_label(run["method"], params, leave_out=KNOB_PARAMS)
    if str((params.get("sweep") or {}).get("series", "")).endswith(EQUAL_TIME_SUFFIX):
        label += " equal time"
    return _old(run, label)


def knob_order(run: Mapping[str, Any]) -> tuple[Any, ...]:
    """Where a run lies along its curve: by spp, N_c, eps, then the termination
    parameters (as text) and the run's id."""
    params = run.get("params") or {}
    nc = params.get("nc")
    return (run["spp"], list(nc) if isinstance(nc, list | tuple) else [nc or 0],
            (params.get("sweep") or {}).get("eps") or 0.0,
            json.dumps(params.get("termination_params"), sort_keys=True), run["id"])
