"""Which runs may share a chart, and the colour of each method configuration.

Two runs are drawn on one error-vs-time plot, one Pareto front or one history chart
only when they measured the same thing: the same resolution, spp and frames, the
same protocol (online training in the frame loop, or a frozen cache of a sweep point),
the same device (times compare on one device only), the same metric version and
both current (or both computed by older estimator versions). :func:`group_of` gives
that key; :func:`split_groups` cuts a list of runs by it.

Colours: a method configuration (its label, e.g. ``nirc (biased, bth, N_c 4)``) gets
one colour of a fixed palette picked by a stable hash of the label, so it has the same
colour on every page and every chart (:func:`colour_of`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

#: Tableau 20: ten hues, each dark and light.
PALETTE = ("#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1",
           "#ff9da7", "#9c755f", "#bab0ac", "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728",
           "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")

ONLINE = "online training"
FROZEN = "frozen cache"


def colour_of(label: str) -> str:
    """The palette colour of a configuration label, the same in every process."""
    index = int.from_bytes(hashlib.sha256(label.encode()).digest()[:4], "big") % len(PALETTE)
    return PALETTE[index]


def protocol_of(params: Mapping[str, Any] | None) -> str:
    """A sweep point renders with a frozen, converged cache; every other run trains its
    cache online, inside the timed frames."""
    return FROZEN if params and "sweep" in params else ONLINE


@dataclass(frozen=True, order=True)
class Group:
    """What runs on one chart have in common."""

    width: int
    height: int
    spp: int
    frames: int
    protocol: str
    device: str
    metric_version: int
    current: bool

    @property
    def title(self) -> str:
        versions = f"metrics v{self.metric_version}" + ("" if self.current else ", old versions")
        return (f"{self.width}×{self.height}, {self.spp} spp, {self.frames} "
                f"frame{'s' if self.frames != 1 else ''}, {self.protocol}, {self.device}, "
                f"{versions}")


def group_of(run: Mapping[str, Any]) -> Group:
    """The group of a run as the REST API lists it (jobs.protocol.results.RunResult)."""
    width, height = run["resolution"]
    return Group(width, height, run["spp"], run["frames"], protocol_of(run["params"]),
                 run["device_key"], run["metric_version"], bool(run["current"]))


def split_groups(runs: Iterable[Mapping[str, Any]]) -> dict[Group, list[Mapping[str, Any]]]:
    """The runs by group, groups in a stable order (largest resolution first)."""
    groups: dict[Group, list[Mapping[str, Any]]] = {}
    for run in runs:
        groups.setdefault(group_of(run), []).append(run)
    return dict(sorted(groups.items(), key=lambda item: (-item[0].width * item[0].height,
                                                          item[0])))


def config_label(run: Mapping[str, Any]) -> str:
    """A run's method configuration: its method label, with its estimator version when
    that is not today's."""
    label = run.get("method_label") or run["method"]
    return label if run.get("current", True) else f"{label} [estimator v{run['estimator_version']}]"
