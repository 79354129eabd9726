"""`reproduce nirc fig13` from stubbed sweep rows (the adaptive sweep itself is tested
in tests/jobs/test_sweep.py): points against % IR bounces with their intervals, the PNG,
and verdicts that turn with the numbers (a planted NIRC of twice NRC's bias at the same
bounces 'does not hold', an equal-time series no better than N_c 1 'not comparable')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nirc_fig13
from jobs.reproduce.registry import Context
from jobs.reproduce.run import reproduce

BOUNCES = (60.0, 40.0, 20.0)                 # % IR bounces at eps 0.05, 0.2, 1
NRC = {"rbias2": (0.2, 0.4, 0.8), "rvar": (0.5, 0.3, 0.2)}
NIRC_RVAR = (0.1, 0.06, 0.04)


def stub_sweep(nirc_bias: float, equal_time_rvar: float, nc: int = 4) -> Any:
    """NRC as above; NIRC's rBias² ``nirc_bias`` x NRC's at each eps; NIRC equal time's
    rVar ``equal_time_rvar`` x NIRC's at N_c ``nc`` (1: NIRC's own renders); every
    interval +-10 %, MRSE = rBias² + rVar."""

    def row(series: str, index: int, rbias2: float, rvar: float, nc: int | None) -> Any:
        values = {"rbias2": rbias2, "rvar": rvar, "mrse": rbias2 + rvar}
        fields = {f: v for key, v in values.items() for f, v in
                  ((key, v), (f"{key}_ci95", [0.9 * v, 1.1 * v]), (f"{key}_ci_note", "t"))}
        return (SimpleNamespace(series=series, eps=(0.05, 0.2, 1.0)[index], nc=nc,
                                ir_bounces_pct=BOUNCES[index], id=hash((series, index)),
                                render_key=f"{series if nc != 1 else 'NIRC'} {index}",
                                flip=0.3, **fields),
                SimpleNamespace(seed_results=[SimpleNamespace(metrics={"flip_hdr": f})
                                              for f in (0.29, 0.3, 0.31)]))

    def eps_sweep(ctx: Any, scene: str, **_options: Any) -> list[tuple[Any, Any]]:
        return [*(row("NIRC", i, nirc_bias * NRC["rbias2"][i], NIRC_RVAR[i], 1) for i in range(3)),
                *(row("NRC", i, NRC["rbias2"][i], NRC["rvar"][i], None) for i in range(3)),
                *(row("NIRC equal time", i, nirc_bias * NRC["rbias2"][i],
                      equal_time_rvar * NIRC_RVAR[i], nc) for i in range(3))]

    return eps_sweep


def test_fig13_points_against_ir_bounces_and_the_png(monkeypatch: pytest.MonkeyPatch,
                                                     tmp_path: Path) -> None:
    monkeypatch.setattr(nirc_fig13, "eps_sweep", stub_sweep(0.5, 0.5))
    result, paths = reproduce("nirc", "fig13", "quick", tmp_path, None, None)
    assert paths["figure"].read_bytes()[:4] == b"\x89PNG"
    assert len(result.points) == 9 * len(nirc_fig13.SCENES)
    nrc = [p for p in result.points if p.series == "NRC" and p.scene == "white-room"]
    assert [p.x for p in nrc] == list(BOUNCES)
    assert nrc[1].values["rbias2"].ci95 == pytest.approx([0.36, 0.44])
    assert "white-room eps 0.2: N_c 4" in result.notes[-1]
    assert [v.verdict for v in result.verdicts] == ["holds"] * 3


@pytest.mark.parametrize(("nirc_bias", "equal_time_rvar", "nc", "expected"), [
    (2.0, 0.5, 4, ["does not hold", "holds", "holds"]),     # planted: NIRC more biased
    (0.5, 1.0, 4, ["holds", "holds", "not comparable"]),    # more N_c, no lower variance
    (0.5, 2.0, 4, ["holds", "holds", "does not hold"]),
    (0.5, 2.0, 1, ["holds", "holds", "not comparable"]),    # N_c 1: NIRC's own renders
])
def test_fig13_verdicts_follow_the_numbers(nirc_bias: float, equal_time_rvar: float, nc: int,
                                           expected: list[str],
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(nirc_fig13, "eps_sweep", stub_sweep(nirc_bias, equal_time_rvar, nc))
    verdicts = nirc_fig13.measure(Context(nirc_fig13.QUICK, None, None)).verdicts
    assert [v.verdict for v in verdicts] == expected
