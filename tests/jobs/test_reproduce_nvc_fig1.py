"""`reproduce nvc fig1` and `fig9` from stubbed stored runs (the renders' FLIP and
timings are tested with the executor): every series with FLIP and its interval, the panels drawn, the
ratios to ReSTIR's beside the paper's, the caches pre-trained, ReSTIR calibrated to
NVC lights' frame time at equal time (Fig. 1's NVC lights run read back), and verdicts
that turn with the numbers (a planted NVC no better than ReSTIR 'does not hold', one
lower within the intervals 'not comparable', a planted Neural DI above NVC lights 'does
not hold', a lower FLIP against a capped ReSTIR calibration 'not comparable')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nvc_compare
from jobs.reproduce.run import reproduce
from tests.jobs.reproduce_fakes import no_drawing

#: ReSTIR's per-seed HDR-FLIP.
RESTIR_FLIP = 0.4


def stub_render(flips: dict[str, float], spread: float,
                calibration: dict[str, Any] | None = None) -> tuple[Any, list[Any]]:
    """Runs whose K seeds' FLIP are ``flips[method]`` +- ``spread``; NVC lights twice
    ReSTIR's frame time; ReSTIR at a time budget stores ``calibration``."""
    asked: list[Any] = []

    def render(ctx: Any, method: str, params: dict[str, Any],
               budget_ms: float | None = None) -> Any:
        asked.append((method, params, budget_ms))
        seeds = [SimpleNamespace(metrics={"flip_hdr": flips[method] + d})
                 for d in (-spread, spread, -spread, spread)]
        seconds = {"restir-di": 0.05, "nvc-lights": 0.1, "neural-di": 0.12}[method]
        return SimpleNamespace(id=len(asked), spp=2 if budget_ms else 1, seed_results=seeds,
                               timings={"seconds_per_frame": seconds},
                               metrics={"calibration": calibration} if budget_ms else {})

    return render, asked


def flips(nvc: float, neural: float) -> dict[str, float]:
    return {"restir-di": RESTIR_FLIP, "nvc-lights": nvc, "neural-di": neural}


def test_fig1_tables_the_three_series_with_ratios_and_draws(monkeypatch: pytest.MonkeyPatch,
                                                            tmp_path: Path) -> None:
    render, asked = stub_render(flips(0.3, 0.2), 0.01)
    monkeypatch.setattr(nvc_compare, "render", render)
    drawn: list[str] = []
    monkeypatch.setattr(nvc_compare, "plot_panels", no_drawing(drawn))
    result, _ = reproduce("nvc", "fig1", "quick", tmp_path, None, None)
    assert drawn == ["flip", "time_ratio"]
    pretrain = nvc_compare.PRETRAIN_PER_FRAME * nvc_compare.QUICK.frames
    assert asked == [("restir-di", {}, None),
                     ("nvc-lights", {"max_depth": 2, "pretrain_frames": pretrain}, None),
                     ("neural-di", {"pretrain_frames": pretrain}, None)]
    nvc = next(p for p in result.points if p.series == nvc_compare.NVC)
    assert nvc.values["flip"].ci95 is not None
    assert nvc.values["flip_ratio"].value == pytest.approx(0.75)
    assert nvc.values["time_ratio"].value == pytest.approx(2.0)
    assert nvc.paper["flip_ratio"] == pytest.approx(0.8)        # 20 % lower
    assert nvc.paper["time_ratio"] == pytest.approx(3.95 / 3.61)
    assert [v.verdict for v in result.verdicts] == ["holds", "holds"]


def test_fig9_calibrates_restir_to_nvc_lights_time(monkeypatch: pytest.MonkeyPatch,
                                                   tmp_path: Path) -> None:
    render, asked = stub_render(flips(0.3, 0.2), 0.01)
    monkeypatch.setattr(nvc_compare, "render", render)
    monkeypatch.setattr(nvc_compare, "plot_panels", no_drawing([]))
    result, _ = reproduce("nvc", "fig9", "quick", tmp_path, None, None)
    assert [(method, budget) for method, _params, budget in asked] == [
        ("nvc-lights", None), ("restir-di", pytest.approx(100.0))]
    assert [p.series for p in result.points] == [nvc_compare.RESTIR, nvc_compare.NVC]
    assert result.points[0].values["spp"].value == 2
    assert result.points[1].paper == {"flip_ratio": pytest.approx(0.55)}   # Sponza's 45 %
    assert [v.verdict for v in result.verdicts] == ["holds"]


#: ReSTIR's calibration records: its largest candidate fits (less than equal time), or
#: not even its least does (more than equal time).
CAPPED = {"capped": True, "fits": True, "chosen": 16}
OVER = {"capped": False, "fits": False, "chosen": 1}


def test_fig9_reads_back_fig1s_runs_where_they_agree(monkeypatch: pytest.MonkeyPatch,
                                                     tmp_path: Path) -> None:
    """Both figures key their runs alike (spec and key name): `--all` renders NVC lights
    once; ReSTIR at equal time is its own run."""
    keys: dict[str, list[tuple[str, str, str | None]]] = {}

    def stored_run(ctx: Any, spec: Any, figure: str | None = None) -> Any:
        keys[current].append((spec.method, spec.key(), figure))
        seeds = [SimpleNamespace(metrics={"flip_hdr": 0.3 + d}) for d in (-0.01, 0.01)]
        return SimpleNamespace(id=1, spp=1, seed_results=seeds, metrics={},
                               timings={"seconds_per_frame": 0.1})

    monkeypatch.setattr(nvc_compare, "stored_run", stored_run)
    monkeypatch.setattr(nvc_compare, "plot_panels", no_drawing([]))
    for current in ("fig1", "fig9"):
        keys[current] = []
        reproduce("nvc", current, "quick", tmp_path / current, None, None)
    fig1 = {method: key for method, *key in keys["fig1"]}
    fig9 = {method: key for method, *key in keys["fig9"]}
    assert fig9["nvc-lights"] == fig1["nvc-lights"]
    assert fig9["restir-di"] != fig1["restir-di"]


@pytest.mark.parametrize(("figure", "nvc", "neural", "spread", "calibration", "expected"), [
    ("fig1", 0.45, 0.2, 0.01, None, ["does not hold", "holds"]),     # planted: NVC noisier
    ("fig1", 0.38, 0.1, 0.05, None, ["not comparable", "holds"]),    # lower, overlapping
    ("fig1", 0.3, 0.35, 0.01, None, ["holds", "does not hold"]),     # planted: DI above NVC
    ("fig9", 0.45, 0.2, 0.01, None, ["does not hold"]),
    # ReSTIR capped below equal time: its lower FLIP decides, NVC's lower one does not.
    ("fig9", 0.45, 0.2, 0.01, CAPPED, ["does not hold"]),
    ("fig9", 0.3, 0.2, 0.01, CAPPED, ["not comparable"]),
    # ReSTIR over equal time: NVC's lower FLIP decides, ReSTIR's lower one does not.
    ("fig9", 0.3, 0.2, 0.01, OVER, ["holds"]),
    ("fig9", 0.45, 0.2, 0.01, OVER, ["not comparable"]),
])
def test_verdicts_follow_the_numbers(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                     figure: str, nvc: float, neural: float, spread: float,
                                     calibration: dict[str, Any] | None,
                                     expected: list[str]) -> None:
    monkeypatch.setattr(nvc_compare, "render",
                        stub_render(flips(nvc, neural), spread, calibration)[0])
    monkeypatch.setattr(nvc_compare, "plot_panels", no_drawing([]))
    result, _ = reproduce("nvc", figure, "quick", tmp_path, None, None)
    assert [v.verdict for v in result.verdicts] == expected
