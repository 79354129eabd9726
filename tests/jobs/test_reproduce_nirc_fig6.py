"""`reproduce nirc fig6` from stubbed stored runs (V_rel itself is tested in
tests/renderers/test_control_variates.py and test_residual_variance.py): its series,
floats per pixel, table and PNG, and verdicts that turn with the numbers (a planted NIRC
above NCV is 'does not hold', overlapping intervals 'not comparable')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nirc_fig6
from jobs.reproduce.registry import Context
from jobs.reproduce.run import reproduce

#: Each series' V_rel (interval +-10 %) and the floats its run stores per pixel.
V_REL = {"cv-sh": 0.5, "cv-vmf": 0.6, "ncv": 0.3, "ss-nirc": 0.25}
STATS = {"cv-sh": {"model": {"floats_per_pixel": {"model": 75, "fit": 76}}},
         "ncv": {"model": {"floats_per_pixel": {"model": 40.5}}},
         "nirc": {"caches": {"cache": {"parameters": 2560}}}}


def stub_sweep(nirc_v_rel: float) -> Any:
    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[Any],
              params: dict[str, Any], max_depth: int = -1) -> list[tuple[Any, Any]]:
        if method == "nirc":
            assert params["estimator"] == "unbiased"
            assert params["cache"]["mlp"]["hidden_layers"] == 6
        value = nirc_v_rel if method == "nirc" else V_REL[method]
        run = SimpleNamespace(
            metrics={"v_rel_mean": value, "v_rel_ci95": [0.9 * value, 1.1 * value]},
            seed_results=[SimpleNamespace(metrics={"method_stats": STATS.get(method, {})})])
        return [(SimpleNamespace(value=values[0], id=1, seconds_per_frame=0.02), run)]

    return sweep


def test_fig6_tables_every_scene_and_series_with_its_floats(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setattr(nirc_fig6, "sweep", stub_sweep(0.1))
    result, paths = reproduce("nirc", "fig6", "quick", tmp_path, None, None)
    assert paths["figure"].read_bytes()[:4] == b"\x89PNG"
    assert len(result.points) == len(nirc_fig6.SCENES) * len(nirc_fig6.SERIES)
    floats = {p.series: p.values["floats_per_pixel"].value for p in result.points}
    assert floats == {"SH": 75, "vMF": None, "NCV": 40.5, "SS NIRC": None,
                      "NIRC": 2560 / nirc_fig6.QUICK.resolution**2}
    assert {p.values["ms_per_frame"].value for p in result.points} == {20.0}
    assert "**holds**" in paths["markdown"].read_text()


@pytest.mark.parametrize(("nirc_v_rel", "below_ncv"), [(0.1, "holds"), (0.5, "does not hold"),
                                                       (0.29, "not comparable")])
def test_fig6_verdicts_follow_the_numbers(nirc_v_rel: float, below_ncv: str,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(nirc_fig6, "sweep", stub_sweep(nirc_v_rel))
    ncv, sh, _vmf, ratio = nirc_fig6.measure(Context(nirc_fig6.QUICK, None, None)).verdicts
    assert ncv.verdict == below_ncv
    assert sh.verdict == ("holds" if nirc_v_rel < 0.4 else "not comparable")
    assert ratio.verdict == "not comparable"
    assert f"{0.3 / nirc_v_rel:.2f}x" in ratio.reason
