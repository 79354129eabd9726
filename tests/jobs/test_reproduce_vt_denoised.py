"""`reproduce vt fig10` and `fig11` from stubbed stored runs (the denoised errors
themselves are tested with metrics/denoised.py): every point is asked for denoised,
its quantities come from the seeds with intervals, and the verdicts turn with the
numbers (planted: area-spread ending paths at the primary hit, area-spread's denoised
error below var-bound's, var-bound never ending at the primary hit)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.protocol.spec import SweepSpec
from jobs.reproduce import vt_fig10, vt_fig11
from jobs.reproduce.registry import Context
from jobs.reproduce.run import reproduce
from tests.jobs.reproduce_fakes import no_drawing

#: A policy's stored numbers by its swept value: (denoised MRSE of 4 frames, % of paths
#: ending at the primary hit, % at the second vertex); PT (0.9) has no cache. The other
#: errors are multiples of the first.
NUMBERS = {0.9: (0.5, None, None), 1.0: (0.1, 20.0, 40.0), 100.0: (0.2, 60.0, 30.0),
           0.01: (0.3, 0.0, 80.0), 10.0: (0.1, 5.0, 20.0)}


def stub_sweep(numbers: dict[float, tuple[float, float | None, float | None]]) -> Any:
    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[Any],
              params: dict[str, Any], max_depth: int = -1,
              denoised: bool = False) -> list[tuple[Any, Any]]:
        assert denoised and len(values) == 1
        accum, primary, second = numbers[values[0]]
        seeds = [SimpleNamespace(metrics={
            "convergence": {"frame_mrse": [2 * accum * k, 3 * accum * k]},
            "denoised_mrse_frame": 1.5 * accum * k, "denoised_mrse_accum": accum * k,
            "denoised_flip_accum": accum * k, "path_stats": {"weighted_length": 2.0 * k},
            "method_stats": {"caches": {"cache": {"preset": "cpu"}}}})
            for k in (0.9, 1.0, 1.1)]
        fractions = (None if primary is None else
                     {"0": 0.0, "1": primary / 100, "2": second / 100})
        run = SimpleNamespace(seed_results=seeds, path_stats={
            "weighted_length": 2.0, **({"cache_depth_fractions": fractions} if fractions
                                       else {})})
        return [(SimpleNamespace(id=int(1000 * values[0]), value=values[0]), run)]

    return sweep


def test_fig10_asks_every_point_denoised_and_tables_it(monkeypatch: pytest.MonkeyPatch,
                                                       tmp_path: Path) -> None:
    drawn: list[str] = []
    monkeypatch.setattr(vt_fig10, "sweep", stub_sweep(NUMBERS))
    monkeypatch.setattr(vt_fig10, "plot_panels", no_drawing(drawn))
    result, paths = reproduce("vt", "fig10", "quick", tmp_path, None, None)
    assert len(result.points) == len(vt_fig10.SCENES) * len(vt_fig10.POLICIES)
    assert set(drawn) == {"mrse_frame", "denoised_mrse_accum"}
    spread = next(p for p in result.points if p.series == vt_fig10.AREA_SPREAD)
    assert spread.values["mrse_frame"].value == pytest.approx(0.75)  # (0.6 + 0.9) / 2
    low, high = spread.values["denoised_mrse_accum"].ci95
    assert low < 0.3 < high
    assert spread.values["primary_pct"].value == 0.0
    assert result.settings["runs' grid presets"] == ["cpu"]
    [verdict] = result.verdicts
    assert verdict.verdict == "holds" and "80 %" in verdict.reason
    assert "Intel Open Image Denoise" in paths["markdown"].read_text()


def test_fig10_verdict_flips_when_area_spread_ends_at_the_primary_hit(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(vt_fig10, "sweep", stub_sweep({**NUMBERS, 0.01: (0.3, 10.0, 70.0)}))
    [verdict] = vt_fig10.measure(Context(vt_fig10.QUICK, None, None)).verdicts
    assert verdict.verdict == "does not hold"


@pytest.mark.parametrize(("spread_accum", "bound_primary", "expected"), [
    (0.3, 5.0, ("holds", "holds")),
    (0.03, 5.0, ("does not hold", "holds")),       # area-spread denoises better
    (0.11, 0.0, ("not comparable", "does not hold")),   # overlap; no primary-hit ends
])
def test_fig11_verdicts_follow_the_numbers(spread_accum: float, bound_primary: float,
                                           expected: tuple[str, str],
                                           monkeypatch: pytest.MonkeyPatch,
                                           tmp_path: Path) -> None:
    drawn: list[str] = []
    numbers = {**NUMBERS, 0.01: (spread_accum, 0.0, 80.0), 10.0: (0.1, bound_primary, 20.0)}
    monkeypatch.setattr(vt_fig10, "sweep", stub_sweep(numbers))
    monkeypatch.setattr(vt_fig11, "plot_panels", no_drawing(drawn))
    result, _paths = reproduce("vt", "fig11", "quick", tmp_path, None, None)
    assert [p.series for p in result.points] == [vt_fig11.VAR_BOUND, vt_fig10.AREA_SPREAD]
    assert tuple(v.verdict for v in result.verdicts) == expected
    assert "denoised_flip_accum" in drawn


def test_a_denoised_sweep_denoises_its_points_and_keeps_older_keys() -> None:
    base = {"scene": "door", "methods": ["pt"], "resolution": 8, "seeds": 2,
            "parameter": {"name": "rr_survival", "values": [0.9]}}
    assert SweepSpec(**base, denoised=True).base_render_spec().denoised
    plain = SweepSpec(**base)
    assert not plain.base_render_spec().denoised and "denoised" not in plain.model_dump()
    with pytest.raises(ValueError, match="denoised"):
        SweepSpec(scene="door", eps=[0.1], denoised=True)
