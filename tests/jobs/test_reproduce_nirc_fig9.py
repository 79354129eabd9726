"""`reproduce nirc fig9` from stubbed sweep points: the splits at a fixed total with
roulette off, the PNG, and a verdict that turns with the numbers (a planted common
optimum 'does not hold', overlapping optima 'not comparable')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nirc_fig9
from jobs.reproduce.registry import Context
from jobs.reproduce.run import reproduce


def stub_sweep(best: dict[str, int], spread: float = 0.05) -> Any:
    """MRSE 1 at each scene's ``best`` N_c¹ and 2 elsewhere, intervals +-``spread``."""

    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[Any],
              params: dict[str, Any], max_depth: int = -1) -> list[tuple[Any, Any]]:
        assert params["estimator"] == "unbiased" and sum(params["nc"]) == nirc_fig9.TOTAL
        assert params["rr_survival"] == 1.0 and max_depth == nirc_fig9.MAX_DEPTH
        mrse = 1.0 if params["nc"][0] == best[scene] else 2.0
        fields = {f: v for key, v in (("mrse", mrse), ("rvar", mrse)) for f, v in
                  ((key, v), (f"{key}_ci95", [v - spread, v + spread]), (f"{key}_ci_note", "t"))}
        row = SimpleNamespace(id=1, flip=0.3, seconds_per_frame=0.01, **fields)
        return [(row, SimpleNamespace(seed_results=[]))]

    return sweep


def test_fig9_splits_at_a_fixed_total_and_the_png(monkeypatch: pytest.MonkeyPatch,
                                                  tmp_path: Path) -> None:
    monkeypatch.setattr(nirc_fig9, "sweep", stub_sweep({"cornell-box": 2, "white-room": 6}))
    result, paths = reproduce("nirc", "fig9", "quick", tmp_path, None, None)
    assert paths["figure"].read_bytes()[:4] == b"\x89PNG"
    assert [p.x for p in result.points] == [2, 4, 6, 2, 4, 6]
    assert result.verdicts[0].verdict == "holds"


@pytest.mark.parametrize(("best", "spread", "expected"), [
    ({"cornell-box": 4, "white-room": 4}, 0.05, "does not hold"),   # planted: one optimum
    ({"cornell-box": 2, "white-room": 6}, 0.6, "not comparable"),   # intervals overlap
])
def test_fig9_verdict_follows_the_numbers(best: dict[str, int], spread: float, expected: str,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(nirc_fig9, "sweep", stub_sweep(best, spread))
    [verdict] = nirc_fig9.measure(Context(nirc_fig9.QUICK, None, None)).verdicts
    assert verdict.verdict == expected
