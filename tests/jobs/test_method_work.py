"""Every method parameter that makes work moves the work estimate (and so the time
estimate, jobs/execution/timecost.py): none can grow a job past the service's bounds
unseen, as ``pretrain_frames: 100000`` once did (estimated at 2 s, stopped only by the
attempt timeout)."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from jobs.execution import method_work
from jobs.execution.work import render_work
from jobs.protocol.spec import RenderSpec
from renderers.methods import METHODS

#: Numeric parameters that do not grow the work as they grow, and why.
DO_NOT_SCALE_WORK = {
    "max_depth": "its default, -1, is no bound at all: roulette ends the paths",
    "sph_c": "a termination threshold: a cache ends a path earlier, never later than roulette",
    "clamp": "a clamp of a cached value",
    "m_clamp": "a clamp of a reservoir's history",
    "spatial_radius": "where the neighbours are picked, not how many",
    "unbiased_every": "fewer unbiased paths as it grows",
    "cell_fraction": "larger grid cells: fewer of them",
    "uniform_fraction": "the share of a first hit's one direction drawn uniformly, not its count",
    "prefill_history": "the pre-fill's averaging window, not its passes (prefill_frames bounds them)",
    "prefill_tolerance": "when the pre-fill stops early; prefill_frames, in the estimate, bounds it",
}


def numeric_fields(method: str) -> list[tuple[str, float, float | None]]:
    """(name, default, upper bound) of each int or float parameter of ``method``."""
    fields = []
    for name, field in METHODS[method].params.model_fields.items():
        if field.annotation in (int, float):
            upper = next((m.le for m in field.metadata if getattr(m, "le", None) is not None),
                         None)
            fields.append((name, field.default, upper))
    return fields


def samples(method: str, params: dict) -> int:
    spec = RenderSpec(scene="cornell-box", method=method, resolution=128, spp=1, frames=2,
                      seeds=1, params=params)
    return render_work(spec, reference_stored=True).samples


def grown(method: str, name: str, default: float, upper: float | None) -> dict | None:
    """The parameters with ``name`` at 100x its default (100 for a 0), else at its upper
    bound; None where neither is valid or neither grows it."""
    for value in (100 * default if default else 100, upper):
        if value is None or value <= default:
            continue
        value = type(default)(value)
        try:
            METHODS[method].params(**{name: value})
        except ValidationError:
            continue
        return {name: value}
    return None


def unseen_growth(methods: list[str]) -> list[str]:
    """'method.name' of each work-making parameter that can grow without the estimate."""
    unseen = []
    for method in methods:
        base = samples(method, {})
        for name, default, upper in numeric_fields(method):
            params = grown(method, name, default, upper)
            if name in DO_NOT_SCALE_WORK or params is None:
                continue
            if samples(method, params) <= base:
                unseen.append(f"{method}.{name}")
    return unseen


def test_every_work_making_parameter_moves_the_estimate():
    assert unseen_growth(sorted(METHODS)) == []


def test_the_walk_finds_a_parameter_left_out_of_the_estimate(monkeypatch):
    """Planted: pre-training frames no longer counted."""
    monkeypatch.setattr(method_work, "WARM_FRAME_PARAMS", ("prefill_frames",))
    assert unseen_growth(["nirc", "nvc-env"]) == ["nirc.pretrain_frames",
                                                  "nvc-env.pretrain_frames"]


@pytest.mark.parametrize("name", ["rr_depth", "rr_survival"])
def test_a_longer_roulette_is_more_work(name):
    longer = {"rr_depth": 50, "rr_survival": 0.99}[name]
    assert samples("pt", {name: longer}) > 2 * samples("pt", {})
