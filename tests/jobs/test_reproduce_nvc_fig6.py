"""`reproduce nvc fig6` from stubbed stored runs (the animated runs' per-frame FLIP is
tested in tests/jobs/test_executor.py): every frame of the three series with its
interval, cold starts of a still scene asked of the render, and verdicts that turn
with the numbers (a planted NVC above ReSTIR at three steps 'does not hold', a flat
curve 'does not hold' for falling FLIP)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nvc_fig6
from jobs.reproduce.run import reproduce
from tests.jobs.reproduce_fakes import no_drawing


def stub_runs(start: dict[str, float], end: dict[str, float],
              spread: float = 0.01) -> tuple[Any, list[Any]]:
    """Runs whose seed-mean FLIP falls linearly from ``start`` to ``end`` per method."""
    asked: list[Any] = []

    def render_series(ctx: Any, method: str, params: dict[str, Any]) -> Any:
        asked.append((method, params, ctx.budget.frames))
        frames = ctx.budget.frames
        mean = [start[method] + (end[method] - start[method]) * f / (frames - 1)
                for f in range(frames)]
        curve = {"mean": mean, "low": [m - spread for m in mean],
                 "high": [m + spread for m in mean]}
        return SimpleNamespace(id=len(asked), metrics={"animation": {"frame_flip": curve}})

    return render_series, asked


FALLING = ({"nrc-di": 0.6, "nvc-lights": 0.3, "restir-di": 0.5},
           {"nrc-di": 0.2, "nvc-lights": 0.15, "restir-di": 0.3})


def test_fig6_tables_every_frame_of_the_three_cold_starts(monkeypatch: pytest.MonkeyPatch,
                                                          tmp_path: Path) -> None:
    render_series, asked = stub_runs(*FALLING)
    monkeypatch.setattr(nvc_fig6, "render_series", render_series)
    drawn: list[str] = []
    monkeypatch.setattr(nvc_fig6, "plot_panels", no_drawing(drawn))
    result, _ = reproduce("nvc", "fig6", "quick", tmp_path, None, None)
    frames = nvc_fig6.QUICK.frames
    assert asked == [("nrc-di", {}, frames), ("nvc-lights", {"max_depth": 2}, frames),
                     ("restir-di", {}, frames)]
    assert nvc_fig6.still(frames).disocclusions == [frames]   # past the last frame
    assert drawn == ["flip"]
    for series, _method, _params in nvc_fig6.SERIES:
        curve = [p for p in result.points if p.series == series]
        assert [p.x for p in curve] == list(range(frames))
        assert curve[0].values["flip"].ci95 is not None
    assert [v.verdict for v in result.verdicts] == ["holds", "holds", "holds"]


def test_fig6_verdicts_follow_the_numbers(monkeypatch: pytest.MonkeyPatch,
                                          tmp_path: Path) -> None:
    start, end = FALLING
    planted = ({**start, "nvc-lights": 0.7, "restir-di": 0.3},   # NVC above ReSTIR early,
               {**end, "restir-di": 0.3})                        # ReSTIR flat
    monkeypatch.setattr(nvc_fig6, "render_series", stub_runs(*planted)[0])
    monkeypatch.setattr(nvc_fig6, "plot_panels", no_drawing([]))
    result, _ = reproduce("nvc", "fig6", "quick", tmp_path, None, None)
    assert [v.verdict for v in result.verdicts] == ["does not hold", "does not hold", "holds"]
