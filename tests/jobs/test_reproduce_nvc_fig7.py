"""`reproduce nvc fig7` from stubbed stored runs (the animated runs' per-frame errors
are tested in tests/jobs/test_executor.py, recoveries in tests/metrics/test_recovery.py):
every frame of both series with its interval, the frames to recover, the PNG, the
disocclusion asked of the render, restir-nvc's frame time over restir-di's beside the
paper's 5 %, and a verdict that turns with the numbers (a planted NVC no better than
ReSTIR at the disocclusion 'does not hold', one lower within the intervals 'not
comparable')"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nvc_fig7
from jobs.reproduce.run import reproduce

#: ReSTIR's seed-mean error (MRSE and FLIP alike) at the disocclusion frame.
PLAIN = 0.8


def stub_runs(nvc_ratio: float, spread: float) -> Any:
    """Runs whose error is 0.2 before the disocclusion frame k, ``PLAIN`` at k and back to
    0.2 after; restir-nvc's at k is ``nvc_ratio`` x ReSTIR's. Intervals +-``spread``."""
    asked: list[tuple[str, Any]] = []

    def render_series(ctx: Any, method: str) -> Any:
        asked.append((method, ctx.budget))
        frames, change = ctx.budget.frames, nvc_fig7.disocclusion_frame(ctx.budget.frames)
        peak = PLAIN * (nvc_ratio if method == "restir-nvc" else 1.0)
        mean = [peak if f == change else 0.2 for f in range(frames)]
        curve = {"mean": mean, "low": [m - spread for m in mean],
                 "high": [m + spread for m in mean]}
        recovery = [{"change_frame": change, "frames": 1, "low": 1.0, "high": 2.0}]
        seconds = 0.11 if method == "restir-nvc" else 0.1
        return SimpleNamespace(id=len(asked), timings={"seconds_per_frame": seconds},
                               metrics={"animation": {"frame_mrse": curve, "frame_flip": curve,
                                                      "recovery": recovery}})

    return render_series, asked


def test_fig7_tables_every_frame_and_the_recovery_and_draws(monkeypatch: pytest.MonkeyPatch,
                                                            tmp_path: Path) -> None:
    render_series, asked = stub_runs(0.5, 0.05)
    monkeypatch.setattr(nvc_fig7, "render_series", render_series)
    result, paths = reproduce("nvc", "fig7", "quick", tmp_path, None, None)
    assert paths["figure"].read_bytes()[:4] == b"\x89PNG"
    frames = nvc_fig7.QUICK.frames
    assert [method for method, _ in asked] == ["restir-di", "restir-nvc"]
    assert nvc_fig7.disocclusion(frames).disocclusions == [frames // 2]
    for series, _ in nvc_fig7.SERIES:
        curve = [p for p in result.points if p.series == series and p.x is not None]
        assert [p.x for p in curve] == list(range(frames))
        assert curve[frames // 2].values["mrse"].ci95 is not None
        recovery = [p for p in result.points if p.series == series and p.x is None]
        assert recovery[0].values["recovery"].ci95 == [1.0, 2.0]
    nvc = recovery[0]   # restir-nvc's: its frame time beside the paper's
    assert nvc.values["frame_time_increase"].value == pytest.approx(10.0)
    assert nvc.paper["frame_time_increase"] == 5
    assert [v.verdict for v in result.verdicts] == ["holds"]


@pytest.mark.parametrize(("nvc_ratio", "spread", "verdict"), [
    (1.2, 0.05, "does not hold"),     # planted: NVC noisier after the disocclusion
    (0.9, 0.2, "not comparable"),     # lower, within the intervals
])
def test_fig7_verdict_follows_the_numbers(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                          nvc_ratio: float, spread: float,
                                          verdict: str) -> None:
    monkeypatch.setattr(nvc_fig7, "render_series", stub_runs(nvc_ratio, spread)[0])
    monkeypatch.setattr(nvc_fig7, "plot_panels", lambda reproduction, panels, path, **_: path)
    result, _ = reproduce("nvc", "fig7", "quick", tmp_path, None, None)
    assert [v.verdict for v in result.verdicts] == [verdict]
