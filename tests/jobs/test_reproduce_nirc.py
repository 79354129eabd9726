"""`reproduce nirc fig4` from stubbed stored points (the sweep is rendered for real in
the vt end-to-end test): its series, its table and PNG, and its verdicts, which must
turn with the numbers (a planted L_V that helps the biased estimator is not 'holds')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import nirc_fig4
from jobs.reproduce.papers import paper_data
from jobs.reproduce.registry import Context
from jobs.reproduce.run import reproduce


def stub_sweep(lv_biased_flip: float) -> Any:
    """A sweep whose runs have FLIP 0.2 (+-0.005 over 3 seeds), biased L_V's
    ``lv_biased_flip``, growing with the epochs for L_V (divergence) by 0.05 from the
    first point to the last, whatever the budget's count of points."""

    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[Any],
              params: dict[str, Any], max_depth: int = -1) -> list[tuple[Any, Any]]:
        assert method == "nirc" and parameter == "pretrain_frames"
        assert params["nc"] == [4] and params["record_depth"] == 1
        out = []
        for index, value in enumerate(values):
            base = 0.2
            if params["loss"] == "variance":
                growth = 0.05 * index / (len(values) - 1)
                base = (lv_biased_flip if params["estimator"] == "biased" else 0.2) + growth
            seeds = [SimpleNamespace(metrics={"flip_hdr": base + d}) for d in (-0.005, 0, 0.005)]
            out.append((SimpleNamespace(value=value, id=index), SimpleNamespace(seed_results=seeds)))
        return out

    return sweep


def test_fig4_draws_its_series_with_intervals_and_its_verdicts(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setattr(nirc_fig4, "sweep", stub_sweep(0.4))
    result, paths = reproduce("nirc", "fig4", "quick", tmp_path, None, None)
    assert paths["figure"].read_bytes()[:4] == b"\x89PNG"
    assert {p.series for p in result.points} == {
        nirc_fig4.series_name(e, loss) for e in nirc_fig4.ESTIMATORS
        for loss in nirc_fig4.losses(nirc_fig4.QUICK)}
    assert all(p.values["flip"].ci95 is not None for p in result.points)
    table = paths["markdown"].read_text()
    assert "**holds**" in table and len(result.claims) == len(paper_data("nirc").of("fig4")[1])


@pytest.mark.parametrize(("lv_flip", "verdict"), [(0.4, "holds"), (0.1, "does not hold"),
                                                  (0.15, "not comparable")])
def test_fig4_verdict_follows_the_numbers(lv_flip: float, verdict: str,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    # L_V's last epoch: lv_flip + 0.05 against L2's 0.2 (intervals +-0.005 over seeds).
    monkeypatch.setattr(nirc_fig4, "sweep", stub_sweep(lv_flip))
    harm, diverge = nirc_fig4.measure(Context(nirc_fig4.QUICK, None, None)).verdicts
    assert harm.verdict == verdict
    assert diverge.verdict == "holds"
