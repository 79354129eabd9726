"""`reproduce nvc fig5` from a stubbed clamp sweep (the sweep's rows are tested in
tests/jobs, clamp 0 biased and 0.001 not in
tests/renderers/test_nvc_lights.py): both floors
asked of nvc-lights at primary hits, rBias² and rVar with their intervals, and
verdicts that turn with the numbers (a planted biased clamped point 'does not hold',
an unclamped point no more biased than the clamped one 'does not hold')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nvc_fig5
from jobs.reproduce.run import reproduce
from tests.jobs.reproduce_fakes import no_drawing


def stub_sweep(bias: dict[float, float], rvar: dict[float, float],
               half_width: float) -> tuple[Any, list[Any]]:
    """Rows whose rBias² is ``bias[clamp]`` +- ``half_width``, rVar ``rvar[clamp]``."""
    asked: list[Any] = []

    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[float],
              params: dict[str, Any], max_depth: int) -> list[tuple[Any, Any]]:
        asked.append((scene, method, parameter, values, params, max_depth))
        rows = []
        for index, clamp in enumerate(values):
            b, v = bias[clamp], rvar[clamp]
            row = SimpleNamespace(id=index, value=clamp, rbias2=b,
                                  rbias2_ci95=[b - half_width, b + half_width],
                                  rbias2_ci_note="t", rvar=v, rvar_ci95=[0.9 * v, 1.1 * v],
                                  rvar_ci_note="jackknife")
            seeds = [SimpleNamespace(metrics={"flip_hdr": 0.3 + d}) for d in (-0.01, 0.01, -0.01, 0.01)]
            rows.append((row, SimpleNamespace(seed_results=seeds)))
        return rows

    return sweep, asked


OFF, ON = nvc_fig5.OFF, nvc_fig5.CLAMPED


def test_fig5_sweeps_the_floor_and_tables_bias_and_variance(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    sweep, asked = stub_sweep({OFF: 0.05, ON: 0.001}, {OFF: 1.0, ON: 1.2}, 0.005)
    monkeypatch.setattr(nvc_fig5, "sweep", sweep)
    drawn: list[str] = []
    monkeypatch.setattr(nvc_fig5, "plot_panels", no_drawing(drawn))
    result, _ = reproduce("nvc", "fig5", "quick", tmp_path, None, None)
    assert asked == [("many-lights", "nvc-lights", "clamp", [OFF, ON], {}, 2)]
    assert drawn == list(nvc_fig5.QUANTITIES)
    clamped = next(p for p in result.points if p.x == ON)
    assert clamped.values["rbias2"].ci95 == pytest.approx([-0.004, 0.006])
    assert clamped.values["flip"].ci95 is not None
    assert [v.verdict for v in result.verdicts] == ["holds", "holds"]


@pytest.mark.parametrize(("bias", "rvar", "expected"), [
    ({OFF: 0.05, ON: 0.02}, {OFF: 1.0, ON: 1.2}, ["does not hold", "holds"]),  # planted bias
    ({OFF: 0.0, ON: 0.001}, {OFF: 1.0, ON: 1.2}, ["holds", "does not hold"]),  # off unbiased
    ({OFF: 0.05, ON: 0.001}, {OFF: 1.2, ON: 1.0}, ["not comparable", "holds"]),  # less var
])
def test_fig5_verdicts_follow_the_numbers(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                          bias: dict[float, float], rvar: dict[float, float],
                                          expected: list[str]) -> None:
    monkeypatch.setattr(nvc_fig5, "sweep", stub_sweep(bias, rvar, 0.005)[0])
    monkeypatch.setattr(nvc_fig5, "plot_panels", no_drawing([]))
    result, _ = reproduce("nvc", "fig5", "quick", tmp_path, None, None)
    assert [v.verdict for v in result.verdicts] == expected
