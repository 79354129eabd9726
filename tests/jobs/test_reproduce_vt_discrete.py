"""`reproduce vt fig4` and `fig5`: the discrete model's figures (the model itself is
tested in tests/renderers/test_termination_model.py). Each writes its table and PNG,
and its verdicts turn with the numbers: planted defects (a wrong blend, a curve that
never leaves the threshold, rules that are optimal or never continue) flip them."""

from __future__ import annotations

from pathlib import Path

import pytest

from jobs.reproduce import vt_fig4, vt_fig5
from jobs.reproduce.results import Estimate
from jobs.reproduce.run import reproduce
from renderers.termination_model import blend, frontier_rule, optimal_frontier
from tests.jobs.reproduce_fakes import no_drawing


def test_fig4_writes_its_table_and_both_claims_hold(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    drawn: list[str] = []
    monkeypatch.setattr(vt_fig4, "plot_panels", no_drawing(drawn))
    result, paths = reproduce("vt", "fig4", "quick", tmp_path, None, None)
    assert drawn == list(vt_fig4.QUANTITIES)
    assert [v.verdict for v in result.verdicts] == ["holds", "holds"]
    assert "| tree | var-bound | 0.01 | 0.01 |" in paths["markdown"].read_text()


def test_fig4_verdicts_flip_on_planted_curves() -> None:
    thresholds = vt_fig4.QUICK.values
    # a used where its square belongs: the variance falls short of t from the start
    squared = vt_fig4.curve(thresholds, lambda rc, le, nxt, ratio, a: blend(rc, le, nxt, ratio,
                                                                             a * a))
    assert [v.verdict for v in vt_fig4.verdicts(squared)] == ["does not hold", "holds"]
    # an MSE that keeps following t never detaches
    following = [p.model_copy(update={"values": {**p.values, "mse": Estimate(value=p.x)}})
                 if p.series == vt_fig4.VAR_BOUND else p for p in vt_fig4.curve(thresholds)]
    assert [v.verdict for v in vt_fig4.verdicts(following)] == ["holds", "does not hold"]


def test_fig5_writes_its_table_and_its_claim_holds(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    drawn: list[str] = []
    monkeypatch.setattr(vt_fig5, "plot_panels", no_drawing(drawn))
    result, paths = reproduce("vt", "fig5", "quick", tmp_path, None, None)
    assert drawn == ["mse", "variance"]
    assert "| tree | exhaustive optimum | 100 | 0.0055 |" in paths["markdown"].read_text()
    [verdict] = result.verdicts
    assert verdict.verdict == "holds", verdict.reason
    assert "s = 100: 4.86x the optimum" in verdict.reason


def test_fig5_verdict_flips_on_planted_rules() -> None:
    targets = vt_fig5.QUICK.values
    optimal = vt_fig5.lines(targets, lambda s: frontier_rule(optimal_frontier(vt_fig5.tree(),
                                                                              s)[0]))
    [verdict] = vt_fig5.verdicts(optimal)
    assert verdict.verdict == "does not hold" and "at 0 of 5" in verdict.reason
    # ending every path at the root: not optimal, but never with more variance (too late)
    root = vt_fig5.lines(targets, lambda s: (lambda state: 0.0))
    [verdict] = vt_fig5.verdicts(root)
    assert verdict.verdict == "does not hold" and "at 0 of them" in verdict.reason
