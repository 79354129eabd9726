"""The points of ``nirc-bench pareto``, planned from the method registry without
rendering: the paper's PT and the strongest PT's candidates at every ``pt_spp``, each
other method at its equal-time knob's values and its comparison runs, and the
baseline the speed-ups are measured against (docs/pareto.md, "The points" and
"The strongest PT").

Kept apart from the rendering and timing (jobs.pareto.pareto) so that the command
refuses a bad option before it imports what renders, times and plots.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import zip_longest
from typing import Any

from jobs.costs.cost_model import DEFAULT_RESOLUTIONS
from jobs.pareto.tradeoff import RESAMPLES
from jobs.protocol.calibration import DEFAULT_ROUNDS
from jobs.protocol.spec import ReferenceSpec, RenderSpec
from jobs.views.baselines import STRONGEST_PT_LABEL, STRONGEST_PT_PARAMS, pt_core_methods
from renderers.methods import BASELINE, METHODS, Method, MethodError, parse_params

#: The two named PT baselines (``--baseline``) and their labels. The paper's PT is the
#: baseline method with its own defaults: Russian roulette of fixed survival 0.9 from the
#: fifth vertex, the NIRC paper's "termination probability of 0.1".
PAPER_PT, STRONGEST_PT = "paper-pt", "strongest-pt"
BASELINE_LABELS = {PAPER_PT: "paper's PT", STRONGEST_PT: STRONGEST_PT_LABEL}


@dataclass(frozen=True)
class Planned:
    """A point to render: a method with parameters and spp, in a series; ``named``: the
    named PT baseline its series is (the paper's PT) or is a candidate of (the strongest
    PT), else ''."""

    series: str
    label: str
    method: str
    params: dict[str, Any]
    spp: int
    named: str = ""


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
    ref_spp: int = ReferenceSpec.model_fields["spp"].default
    timing_rounds: int = DEFAULT_ROUNDS
    probe_frames: int = 3
    resamples: int = RESAMPLES
    project_res: tuple[int, int] | None = None
    cost_resolutions: list[int] = field(
        default_factory=lambda: list(DEFAULT_RESOLUTIONS))
    baseline: str = STRONGEST_PT
    #: Stages whose time is also shown taken out (a series "<method> without <stage>"
    #: beside each point that ran it; jobs.pareto.pareto.without_stage_points).
    without_stages: list[str] = field(default_factory=list)
    #: Whether points timed on a loaded machine take part in the fronts, baselines and
    #: speed-ups (by default they are left out and listed).
    allow_loaded: bool = False


#: A series as :func:`baseline_series` reads it: its label, the named PT baseline it is
#: part of ('' for none) and its number of points.
SeriesInfo = tuple[str, str, int]


def baseline_series(baseline: str, series: list[SeriesInfo]) -> list[str]:
    """The labels of the series ``baseline`` names ('paper-pt', 'strongest-pt' or a
    series' label); MethodError for a name that is none of them or a series of fewer
    than two points (a baseline's curve is interpolated between its points)."""
    named = [label for label, named, _ in series if named == baseline]
    if named:
        return named
    found = [count for label, _, count in series if label == baseline]
    if not found:
        labels = [label for label, _, count in series if count > 1]
        raise MethodError(f"unknown baseline '{baseline}': give {PAPER_PT}, {STRONGEST_PT} or "
                          f"the label of a series of this call ({', '.join(labels)})")
    if found[0] < 2:
        raise MethodError(f"baseline '{baseline}' is a single point: a baseline needs a curve "
                          "of at least two points")
    return [baseline]


def series_info(series: list[list[Planned]]) -> list[SeriesInfo]:
    """The planned series as :func:`baseline_series` reads them."""
    return [(points[0].series, points[0].named, len(points)) for points in series]


def baseline_label(baseline: str) -> str:
    """How tables name the baseline: the named PT's label, or the series' own."""
    return BASELINE_LABELS.get(baseline, baseline)


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
    for stage in spec.without_stages:
        if not stage.isidentifier() or stage == "render":
            raise MethodError(f"--without-stage '{stage}': name a stage other than render "
                              "that a method times (e.g. propagation, training)")
    series, skipped = _pt_series(spec), []
    for name in names:
        if name in spec.knob_values and (METHODS[name].knob is None or name == BASELINE):
            raise MethodError(f"method '{name}' has no equal-time knob to give values for"
                              + (" (its spp values are --pt-spp)" if name == BASELINE else ""))
        if name == BASELINE:     # its series is the paper's PT, above
            continue
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
    baseline_series(spec.baseline, series_info(series))
    return series, skipped


def _pt_series(spec: ParetoSpec) -> list[list[Planned]]:
    """The paper's PT (the baseline method's defaults) and every candidate of the strongest
    PT (:func:`pt_core_methods` with :data:`STRONGEST_PT_PARAMS`), each over ``pt_spp``."""
    def over_spp(series: str, name: str, params: dict[str, Any], named: str) -> list[Planned]:
        return [Planned(series, f"{series} spp={v}", name, params, v, named)
                for v in sorted(set(spec.pt_spp))]

    def shared(name: str) -> dict[str, Any]:
        return METHODS[name].shared_params(spec.max_depth, spec.pretrain_frames)

    return [over_spp(BASELINE_LABELS[PAPER_PT], BASELINE, shared(BASELINE), PAPER_PT),
            *(over_spp(f"{METHODS[name].label or name} (throughput RR)", name,
                       {**shared(name), **STRONGEST_PT_PARAMS}, STRONGEST_PT)
              for name in pt_core_methods())]


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
    """A method other than the baseline over its knob's values, plus each of its
    comparison runs not on that knob's curve as a series of one point."""
    label = method.label or name
    shared = method.shared_params(spec.max_depth, spec.pretrain_frames)
    knob = method.knob
    on_knob = knob is not None and knob.usable(shared)
    found = []
    if on_knob:
        # An spp knob runs on the baseline's spp grid, so the curves share their x values.
        grid = spec.pt_spp if knob.name == "spp" else knob.candidates
        values = spec.knob_values.get(name, grid)
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
