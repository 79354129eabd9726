"""`reproduce nirc fig6` from stubbed stored runs and stubbed training curves (V_rel
itself is tested in tests/renderers/test_control_variates.py and
test_residual_variance.py): its series, floats per pixel, EMA curves, table and PNGs
(the integrand images' data stubbed: tests/jobs/test_reproduce_nirc_fig6_integrands.py),
and verdicts that turn with the numbers (a planted NIRC above NCV is 'does not hold',
overlapping intervals 'not comparable'); the moving average leaves out frames without a
V_rel (planted: one that averages them in)."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nirc_fig6
from jobs.reproduce import nirc_fig6_curves as curves
from jobs.reproduce.registry import Context
from jobs.reproduce.run import reproduce

#: Each series' V_rel (interval +-10 %) and the floats its run stores per pixel.
V_REL = {"cv-sh": 0.5, "cv-vmf": 0.6, "ncv": 0.3, "ss-nirc": 0.25}
STATS = {"cv-sh": {"model": {"floats_per_pixel": {"model": 75, "fit": 76}}},
         "ncv": {"model": {"floats_per_pixel": {"model": 40.5}}},
         "nirc": {"caches": {"cache": {"parameters": 2560}}}}


#: Each curve's V_rel per frame (stubbed): NCV's has a frame without one.
CURVES = {"ncv": [2.0, None, 1.0, float("nan")] + [1.0] * 60, "nirc": [1.0] * 64}


@pytest.fixture(autouse=True)
def stub_curves(monkeypatch: pytest.MonkeyPatch) -> None:
    """No scene, reference or training for the EMA curves: their V_rel per frame."""
    monkeypatch.setattr(nirc_fig6, "scene_and_reference",
                        lambda ctx, name: (name, SimpleNamespace(mean=None)))

    def v_rel_curve(train: Any, scene: str, params: Any, seed_parts: tuple[Any, ...],
                    frames: int, reference: Any, eps: float) -> list[float | None]:
        return CURVES[seed_parts[2]][:frames]

    monkeypatch.setattr(curves, "v_rel_curve", v_rel_curve)
    monkeypatch.setattr(nirc_fig6.integrands, "measure_integrands", stub_integrands)


def stub_integrands(ctx: Any, series: dict[str, dict[str, Any]]) -> Any:
    """No training or reference paths for the integrand images: constant images, one
    pixel, the series' labels the figure passes."""
    import numpy as np

    columns = [nirc_fig6.integrands.REFERENCE, *series]
    return nirc_fig6.integrands.Integrands("cornell-box", [(3, 8)], columns,
                                           np.full((1, len(columns), 4, 8), 0.1), 8,
                                           ctx.budget.frames)


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
    assert (paths["figure"].parent / "ema.png").read_bytes()[:4] == b"\x89PNG"
    assert (paths["figure"].parent / "integrands.png").read_bytes()[:4] == b"\x89PNG"
    assert "\"images\"" not in paths["json"].read_text()   # the data is not in the table
    table = [p for p in result.points if "v_rel" in p.values]
    # --quick has no equal-memory series (--full's 32x32 has both).
    assert len(table) == len(nirc_fig6.SCENES) * len(nirc_fig6.SERIES)
    assert "floats" not in result.x_label      # the axis names the series measured alone
    assert [s[0] for s in nirc_fig6.equal_memory_series(nirc_fig6.FULL.resolution)] == \
        list(nirc_fig6.EQUAL_LABELS)
    floats = {p.series: p.values["floats_per_pixel"].value for p in table}
    nirc_floats = 2560 / nirc_fig6.QUICK.resolution**2
    assert floats == {"SH": 75, "vMF": None, "NCV": 40.5, "SS NIRC": None, "NIRC": nirc_floats}
    assert {p.values["ms_per_frame"].value for p in table} == {20.0}
    assert "**holds**" in paths["markdown"].read_text()

    frames = nirc_fig6.CURVE_FRAMES[nirc_fig6.QUICK]
    for series, method in (("NCV EMA", "ncv"), ("NIRC EMA", "nirc")):
        ema = {p.x: p.values["v_rel_ema"].value for p in result.points
               if (p.scene, p.series) == ("sky", series)}
        assert sorted(ema) == curves.kept_frames(frames)
        assert ema[frames] == curves.moving_average(CURVES[method][:frames])[0][-1]
    assert f"{2 * len(nirc_fig6.SCENES)} frames without a V_rel" in " ".join(result.notes)


def test_the_moving_average_leaves_out_frames_without_a_v_rel() -> None:
    """EMA_t = 0.95 EMA_{t-1} + 0.05 V_rel_t from the first finite value on; a missing or
    non-finite V_rel keeps the average and is counted. Planted: the plain recursion,
    which carries the NaN into every later frame."""
    values = [None, 4.0, float("nan"), 2.0]
    averages, missing = curves.moving_average(values)
    assert averages[:3] == [None, 4.0, 4.0] and missing == 2
    assert averages[3] == pytest.approx(0.95 * 4.0 + 0.05 * 2.0)

    def plain(values: list[float]) -> float:
        average = values[0]
        for value in values[1:]:
            average = 0.95 * average + 0.05 * value
        return average

    assert math.isnan(plain([4.0, float("nan"), 2.0]))


def test_kept_frames_double_and_end_at_the_last() -> None:
    assert curves.kept_frames(16) == [1, 2, 3, 4, 6, 8, 12, 16]
    assert curves.kept_frames(4000)[-3:] == [2048, 3072, 4000]


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
