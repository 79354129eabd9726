"""`reproduce nirc fig15` from stubbed sweep points: the depths swept with every path
ended into the cache at v1, the PNG, and a verdict that turns with the numbers (a
planted deeper cache of higher error 'does not hold', overlapping 'not comparable')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nirc_fig15
from jobs.reproduce.registry import Context
from jobs.reproduce.run import reproduce


def stub_sweep(slope: float, spread: float = 0.05) -> Any:
    """rBias² = 1 + ``slope`` x (D - 1) (and MRSE alike), intervals +-``spread``."""

    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[Any],
              params: dict[str, Any], max_depth: int = -1) -> list[tuple[Any, Any]]:
        assert parameter == "cache.mlp.hidden_layers" and params["termination"] == "adaptive"
        rows = []
        for depth in values:
            v = 1.0 + slope * (depth - 1)
            fields = {f: x for key in ("rbias2", "mrse") for f, x in
                      ((key, v), (f"{key}_ci95", [v - spread, v + spread]),
                       (f"{key}_ci_note", "t"))}
            rows.append((SimpleNamespace(id=depth, value=depth, seconds_per_frame=0.01,
                                         **fields), None))
        return rows

    return sweep


def test_fig15_depths_and_the_png(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setattr(nirc_fig15, "sweep", stub_sweep(-0.1))
    result, paths = reproduce("nirc", "fig15", "quick", tmp_path, None, None)
    assert paths["figure"].read_bytes()[:4] == b"\x89PNG"
    assert [p.x for p in result.points] == [*nirc_fig15.QUICK.values] * 2
    assert result.verdicts[0].verdict == "holds"


@pytest.mark.parametrize(("slope", "spread", "expected"), [
    (0.1, 0.05, "does not hold"),      # planted: deeper caches worse
    (-0.1, 0.6, "not comparable"),     # intervals overlap
])
def test_fig15_verdict_follows_the_numbers(slope: float, spread: float, expected: str,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(nirc_fig15, "sweep", stub_sweep(slope, spread))
    [verdict] = nirc_fig15.measure(Context(nirc_fig15.QUICK, None, None)).verdicts
    assert verdict.verdict == expected
