"""The points of ``nirc-bench pareto``, planned from the method registry without
rendering: the baseline at every ``pt_spp``, each other method at its equal-time
knob's values and its comparison runs (docs/pareto.md, "The points").

Kept apart from the rendering and timing (jobs.pareto.pareto) so that the command
refuses a bad option before it imports what renders, times and plots.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import zip_longest
from typing import Any

from jobs.pareto.tradeoff import RESAMPLES
from jobs.protocol.calibration import DEFAULT_ROUNDS
from jobs.protocol.cost_model import DEFAULT_RESOLUTIONS
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from renderers.methods import BASELINE, METHODS, Method, MethodError, parse_params


@dataclass(frozen=True)
class Planned:
    """A point to render: a method with parameters and spp, in a series."""

    series: str
    label: str
    method: str
    params: dict[str, Any]
    spp: int


@dataclass
class ParetoSpec:
    """What ``nirc-bench pareto`` runs (CLI options, validated by :func:`plan`)."""

    scene: str
    resolution: int = 32
    frames: int = 8
    seeds: int = 2
    pt_spp: list[int] = field(default_factory=lambda: [1, 2, 4, 8, 16])
    knob_values: dict[str, list[int]] = field(default_factory=dict)
    methods: list[str] | None = None
    pretrain_frames: int = 16
    max_depth: int = -1
    ref_spp: int = 1024
    timing_rounds: int = DEFAULT_ROUNDS
    probe_frames: int = 3
    resamples: int = RESAMPLES
    project_res: tuple[int, int] | None = None
    cost_resolutions: list[int] = field(
        default_factory=lambda: list(DEFAULT_RESOLUTIONS))


def knob_methods() -> list[str]:
    """The methods whose knob values a bare ``--knob-values LIST`` sets: those other than
    the baseline with an equal-time knob that is not spp (an spp knob runs on the
    baseline's ``pt_spp`` grid unless given by name)."""
    return [name for name, method in METHODS.items()
            if method.knob is not None and method.knob.name != "spp" and name != BASELINE]


def plan(spec: ParetoSpec) -> tuple[list[list[Planned]], list[dict[str, str]]]:
    """The series to render (each a list of points) and the methods skipped for want of
    a knob or comparison runs; MethodError for options the registry contradicts."""
    names = list(dict.fromkeys(spec.methods if spec.methods is not None else METHODS))
    for name in [*names, *spec.knob_values]:
        if name not in METHODS:
            raise MethodError(f"unknown method '{name}'; available: {', '.join(METHODS)}")
    if BASELINE not in names:
        raise MethodError(f"the baseline '{BASELINE}' must be among the methods: the "
                          "speed-ups are measured against it")
    if spec.project_res is not None and len(set(spec.cost_resolutions)) < 2:
        raise MethodError("give at least two --cost-res resolutions: the cost model fits a "
                          "line through them")
    if len(set(spec.pt_spp)) < 2:
        raise MethodError(f"give at least two {BASELINE} spp values: its error-vs-time curve "
                          "is interpolated between them")
    series, skipped = [], []
    for name in names:
        if name in spec.knob_values and (METHODS[name].knob is None or name == BASELINE):
            raise MethodError(f"method '{name}' has no equal-time knob to give values for"
                              + (" (its spp values are --pt-spp)" if name == BASELINE else ""))
        found = _method_series(name, METHODS[name], spec)
        if not found:
            skipped.append({"method": name, "reason": "declares neither an equal-time knob "
                                                      "nor comparison runs"})
            continue
        # A method the user did not name (in methods or knob values) that cannot render
        # at the comparison's shared settings (a direct-light method at unbounded depth)
        # is skipped, saying why; a named one is validated below, so the error says what.
        named = name in (spec.methods or ()) or name in spec.knob_values
        misfit = "" if named else _misfit_reason(found)
        if misfit:
            skipped.append({"method": name, "reason": misfit})
            continue
        series += found
    for point in (p for points in series for p in points):
        parse_params(point.method, point.params)
        run_spec(spec, point)
    return series, skipped


def _misfit_reason(found: list[list[Planned]]) -> str:
    """Why a method's points do not validate (empty when they all do)."""
    for point in (p for points in found for p in points):
        try:
            parse_params(point.method, point.params)
        except MethodError as err:
            return f"not comparable at these settings: {err}"
    return ""


def run_spec(spec: ParetoSpec, point: Planned) -> RenderSpec:
    """The render job of ``point`` (validated: a bad value is an error before any render)."""
    return RenderSpec(scene=spec.scene, method=point.method, params=point.params,
                      resolution=spec.resolution, spp=point.spp, frames=spec.frames,
                      seeds=spec.seeds, reference=ReferenceSpec(spp=spec.ref_spp))


def _method_series(name: str, method: Method, spec: ParetoSpec) -> list[list[Planned]]:
    """The baseline over ``pt_spp``; another method over its knob's values, plus each of
    its comparison runs not on that knob's curve as a series of one point."""
    label = method.label or name
    shared = method.shared_params(spec.max_depth, spec.pretrain_frames)
    knob = method.knob
    on_knob = knob is not None and knob.usable(shared)
    found = []
    if on_knob:
        # An spp knob runs on the baseline's spp grid, so the curves share their x values.
        grid = spec.pt_spp if knob.name == "spp" else knob.candidates
        values = spec.pt_spp if name == BASELINE else spec.knob_values.get(name, grid)
        found.append([Planned(label, f"{label} {knob.name}={v}", name,
                              shared if knob.name == "spp" else knob.apply(shared, v),
                              v if knob.name == "spp" else 1)
                      for v in sorted(set(values))])
    for entry in method.comparison:
        params = {**shared, **entry.params}
        if not (knob is not None and knob.usable(params)):
            found.append([Planned(entry.label, entry.label, name, params, entry.spp)])
    return found


def interleave(series: list[list[Planned]]) -> list[Planned]:
    """The points in round-robin order over the series (first of each, then second ...)."""
    return [p for group in zip_longest(*series) for p in group if p is not None]
