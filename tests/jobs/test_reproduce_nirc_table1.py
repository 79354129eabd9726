"""`reproduce nirc table1` from stubbed stored runs (the stage clocks themselves are
tested with renderers/timing.py): shares of the stages' sum on both clocks beside the
paper's, the PNG, and verdicts that turn with the numbers (a planted render share
outside the paper's range is not 'holds')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nirc_table1
from jobs.reproduce.registry import Context
from jobs.reproduce.run import reproduce


def stub_sweep(render_ms: float) -> Any:
    """Runs whose kernel parts are render ``render_ms``, training paths 5, training 20,
    inference 25 ms (and 'other' 50, left out), wall parts twice those."""
    kernel = {"render": render_ms, "training_paths": 5.0, "training": 20.0,
              "inference": 25.0, "other": 50.0}

    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[Any],
              params: dict[str, Any], max_depth: int = -1) -> list[tuple[Any, Any]]:
        assert method == "nirc" and params == nirc_table1.PARAMS
        row = SimpleNamespace(id=7, kernel_breakdown_ms=kernel,
                              time_breakdown_ms={k: 2 * v for k, v in kernel.items()})
        return [(row, None)]

    return sweep


def test_table1_shares_on_both_clocks_beside_the_papers(monkeypatch: pytest.MonkeyPatch,
                                                        tmp_path: Path) -> None:
    monkeypatch.setattr(nirc_table1, "sweep", stub_sweep(50.0))
    result, paths = reproduce("nirc", "table1", "quick", tmp_path, None, None)
    assert paths["figure"].read_bytes()[:4] == b"\x89PNG"
    kernel, wall = (p for p in result.points if p.scene == "white-room")
    assert kernel.values["render"].value == pytest.approx(50.0)    # 50 of 100 ms
    assert kernel.values["training"].value == pytest.approx(20.0)
    assert wall.values["render"].value == pytest.approx(50.0)
    assert kernel.values["frame_ms"].value == 100.0 and wall.values["frame_ms"].value == 200.0
    # White Room: 10.7 of 10.7 + 0.52 + 5.43 + 3.14 + 3.96 ms
    assert kernel.paper["render"] == pytest.approx(100 * 10.7 / 23.75)
    assert kernel.paper["encoding"] == pytest.approx(100 * 3.14 / 23.75)
    assert wall.paper == {} and "encoding" not in kernel.values
    assert [v.verdict for v in result.verdicts] == ["holds", "holds"]


def test_table1_verdict_turns_with_a_share_outside_the_papers_range(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(nirc_table1, "sweep", stub_sweep(350.0))   # render 87.5 %
    render, training = nirc_table1.measure(Context(nirc_table1.QUICK, None, None)).verdicts
    assert render.verdict == "not comparable" and "87.5 %" in render.reason
    assert training.verdict == "not comparable"                  # training 5 %
