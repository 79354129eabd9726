"""`reproduce nirc fig12` from stubbed sweep points (the heuristics are tested in
tests/renderers, the sweeps in tests/jobs/test_sweep.py): a point per heuristic and
scene, the PNG, and verdicts that turn with the numbers (a planted NIRC SPH more biased
than NRC's, a planted BTH noisier than SPH: 'does not hold')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nirc_fig12
from jobs.reproduce.registry import Context
from jobs.reproduce.run import reproduce

#: (rBias², rVar, % IR bounces) per series; NIRC SPH's rBias² and BTH's rVar are scaled.
BASE = {"NRC SPH": (0.4, 0.3, 60.0), "NIRC SPH": (0.4, 0.3, 60.0),
        "NIRC BTH": (0.8, 0.3, 20.0), "NIRC": (0.2, 0.2, 40.0), "NRC": (0.3, 0.2, 40.0)}


def stub(sph_bias: float, bth_rvar: float) -> tuple[Any, Any]:
    """NIRC SPH's rBias² ``sph_bias`` x NRC SPH's, BTH's rVar ``bth_rvar`` x SPH's; every
    interval +-10 %."""

    def point(series: str) -> tuple[Any, Any]:
        rbias2, rvar, bounces = BASE[series]
        rbias2 *= sph_bias if series == "NIRC SPH" else 1.0
        rvar *= bth_rvar if series == "NIRC BTH" else 1.0
        values = {"rbias2": rbias2, "rvar": rvar, "mrse": rbias2 + rvar}
        fields = {f: v for key, v in values.items() for f, v in
                  ((key, v), (f"{key}_ci95", [0.9 * v, 1.1 * v]), (f"{key}_ci_note", "t"))}
        row = SimpleNamespace(id=1, series=series, flip=0.3, ir_bounces_pct=bounces,
                              avg_path_length=2.0, **fields)
        return row, SimpleNamespace(seed_results=[SimpleNamespace(metrics={"flip_hdr": 0.3})])

    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[Any],
              params: dict[str, Any], max_depth: int = -1) -> list[tuple[Any, Any]]:
        assert parameter == "termination"
        assert params["pretrain_frames"] == nirc_fig12.PRETRAIN_PER_FRAME * ctx.budget.frames
        return [point(f"{method.upper()} {values[0].upper()}")]

    def eps_sweep(ctx: Any, scene: str, equal_time: bool = True, **_: Any) -> Any:
        assert not equal_time
        return [point("NIRC"), point("NRC")]

    return sweep, eps_sweep


def test_fig12_a_point_per_heuristic_and_scene_and_the_png(monkeypatch: pytest.MonkeyPatch,
                                                          tmp_path: Path) -> None:
    sweep, eps_sweep = stub(0.5, 0.5)
    monkeypatch.setattr(nirc_fig12, "sweep", sweep)
    monkeypatch.setattr(nirc_fig12, "eps_sweep", eps_sweep)
    result, paths = reproduce("nirc", "fig12", "full", tmp_path, None, None)
    assert paths["figure"].read_bytes()[:4] == b"\x89PNG"
    series = [p.series for p in result.points if p.scene == "door"]
    assert series == ["NRC SPH", "NIRC SPH", "NIRC BTH", "NIRC adaptive", "NRC adaptive"]
    assert [p.x for p in result.points if p.scene == "door"] == [0, 1, 2, 3, 4]
    assert "3 NIRC adaptive" in result.x_label and "4 NRC adaptive" in result.x_label
    assert [v.verdict for v in result.verdicts] == ["holds", "holds"]
    assert "NRC / NIRC 2.00x" in result.verdicts[0].reason


def test_fig12_quick_leaves_out_the_adaptive_series(monkeypatch: pytest.MonkeyPatch) -> None:
    sweep, eps_sweep = stub(0.5, 0.5)
    monkeypatch.setattr(nirc_fig12, "sweep", sweep)
    monkeypatch.setattr(nirc_fig12, "eps_sweep", eps_sweep)
    result = nirc_fig12.measure(Context(nirc_fig12.QUICK, None, None))
    assert {p.series for p in result.points} == {"NRC SPH", "NIRC SPH", "NIRC BTH"}
    assert "adaptive" not in result.x_label   # the axis names only the drawn series
    assert [v.verdict for v in result.verdicts] == ["holds", "holds"]


@pytest.mark.parametrize(("sph_bias", "bth_rvar", "expected"), [
    # planted: NIRC SPH more biased than NRC's (and as biased as BTH: no bias traded)
    (2.0, 0.5, ["does not hold", "not comparable"]),
    (0.5, 2.0, ["holds", "does not hold"]),           # planted: BTH noisier than SPH
    (0.95, 1.0, ["not comparable", "not comparable"]),
])
def test_fig12_verdicts_follow_the_numbers(sph_bias: float, bth_rvar: float,
                                           expected: list[str],
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    sweep, eps_sweep = stub(sph_bias, bth_rvar)
    monkeypatch.setattr(nirc_fig12, "sweep", sweep)
    monkeypatch.setattr(nirc_fig12, "eps_sweep", eps_sweep)
    verdicts = nirc_fig12.measure(Context(nirc_fig12.QUICK, None, None)).verdicts
    assert [v.verdict for v in verdicts] == expected
