"""`reproduce nirc fig11` from stubbed sweep points: NIRC and NIRC with the
environment's visibility cache over training frames, and a verdict that turns with the
numbers (a planted NVC of higher error 'does not hold', overlapping 'not comparable')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nirc_fig11
from jobs.reproduce.registry import Context
from jobs.reproduce.run import reproduce
from tests.jobs.reproduce_fakes import no_drawing


def stub_sweep(nvc_factor: float, spread: float = 0.05) -> Any:
    """MRSE and rVar 1 / (1 + frames / 16) for NIRC, ``nvc_factor`` times that for NVC,
    intervals +-``spread`` of the value."""

    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[Any],
              params: dict[str, Any], max_depth: int = -1) -> list[tuple[Any, Any]]:
        assert scene == "sky" and parameter == "pretrain_frames"
        assert params["estimator"] == "unbiased" and params["nc"] == [nirc_fig11.NC]
        factor = nvc_factor if method == "nirc-nvc-env" else 1.0
        rows = []
        for frames in values:
            v = factor / (1.0 + frames / 16)
            fields = {f: x for key in ("mrse", "rvar") for f, x in
                      ((key, v), (f"{key}_ci95", [v * (1 - spread), v * (1 + spread)]),
                       (f"{key}_ci_note", "t"))}
            run = SimpleNamespace(seed_results=[SimpleNamespace(metrics={"flip_hdr": 0.1})] * 2,
                                  metrics={"v_rel_mean": v})
            rows.append((SimpleNamespace(id=1, value=frames, flip=0.1, **fields), run))
        return rows

    return sweep


def test_fig11_series_over_training(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    drawn: list[str] = []
    monkeypatch.setattr(nirc_fig11, "sweep", stub_sweep(0.5))
    monkeypatch.setattr(nirc_fig11, "plot_panels", no_drawing(drawn))
    result, _paths = reproduce("nirc", "fig11", "quick", tmp_path, None, None)
    assert drawn == list(nirc_fig11.QUANTITIES)
    frames = [v + nirc_fig11.QUICK.frames for v in nirc_fig11.QUICK.values]
    assert [p.x for p in result.points] == frames * 2
    assert result.verdicts[0].verdict == "holds"


@pytest.mark.parametrize(("nvc_factor", "spread", "expected"), [
    (2.0, 0.05, "does not hold"),      # planted: NVC's error higher
    (0.9, 0.3, "not comparable"),      # intervals overlap
])
def test_fig11_verdict_follows_the_numbers(nvc_factor: float, spread: float, expected: str,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(nirc_fig11, "sweep", stub_sweep(nvc_factor, spread))
    [verdict] = nirc_fig11.measure(Context(nirc_fig11.QUICK, None, None)).verdicts
    assert verdict.verdict == expected
