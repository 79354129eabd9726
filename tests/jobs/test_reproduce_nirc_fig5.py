"""`reproduce nirc fig5` from stubbed sweep points: biased NIRC's frame time against N_c,
the fitted cost of one more neural sample and its share of a PT frame, with a verdict
that turns with the timings (a planted costly neural sample 'does not hold', noisy
timings 'not comparable')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from jobs.reproduce import nirc_fig5
from jobs.reproduce.registry import Context
from jobs.reproduce.run import reproduce
from tests.jobs.reproduce_fakes import no_drawing

PT_SECONDS = 0.010


def stub_sweep(per_sample_s: float, noise_s: float) -> Any:
    """NIRC frames of 20 ms + ``per_sample_s`` per neural sample, PT frames of 10 ms, each
    seed's time off by Gaussian noise of deviation ``noise_s``."""
    rng = np.random.default_rng(5)

    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[Any],
              params: dict[str, Any], max_depth: int = -1) -> list[tuple[Any, Any]]:
        assert scene == "sky"
        if method == "pt":
            mean = PT_SECONDS
        else:
            assert params["estimator"] == "biased"
            mean = 0.020 + per_sample_s * params["nc"][0]
        seeds = [SimpleNamespace(metrics={"seconds_per_frame": mean + noise_s * z})
                 for z in rng.standard_normal(ctx.budget.seeds)]
        return [(SimpleNamespace(id=1), SimpleNamespace(seed_results=seeds))]

    return sweep


def test_fig5_slope_and_share(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    drawn: list[str] = []
    monkeypatch.setattr(nirc_fig5, "sweep", stub_sweep(0.0001, 0.00002))
    monkeypatch.setattr(nirc_fig5, "plot_panels", no_drawing(drawn))
    result, _paths = reproduce("nirc", "fig5", "quick", tmp_path, None, None)
    assert drawn == ["ms_per_frame"]
    [fit] = [p for p in result.points if p.series == "fit"]
    slope = fit.values["slope_ms"]
    assert slope.ci95[0] < 0.1 < slope.ci95[1]          # 0.1 ms per neural sample
    assert fit.values["share_of_pt"].value == pytest.approx(0.01, rel=0.2)
    assert [v.verdict for v in result.verdicts] == ["not comparable", "holds"]


@pytest.mark.parametrize(("per_sample_s", "noise_s", "expected"), [
    (0.001, 0.00002, "does not hold"),   # planted: a neural sample costs 10 % of PT
    (0.0002, 0.01, "not comparable"),    # timings too noisy to tell
])
def test_fig5_verdict_follows_the_timings(per_sample_s: float, noise_s: float,
                                          expected: str,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(nirc_fig5, "sweep", stub_sweep(per_sample_s, noise_s))
    verdicts = nirc_fig5.measure(Context(nirc_fig5.QUICK, None, None)).verdicts
    assert verdicts[1].verdict == expected
