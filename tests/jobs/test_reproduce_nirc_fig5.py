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

PT_MS = 10.0


def stub_sweep(per_sample_ms: float, noise_ms: float, pt_harness: float = 0.2) -> Any:
    """NIRC's render and inference stages 20 ms + ``per_sample_ms`` per neural sample, off
    by Gaussian noise of deviation ``noise_ms`` (400 ms of training on top); PT frames of
    10 ms, ``pt_harness`` of them outside kernels."""
    rng = np.random.default_rng(5)

    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[Any],
              params: dict[str, Any], max_depth: int = -1) -> list[tuple[Any, Any]]:
        assert scene == "sky"
        if method == "pt":
            row = SimpleNamespace(id=1, seconds_per_frame=PT_MS / 1e3, time_breakdown_ms={},
                                  harness_share=pt_harness)
        else:
            assert params["estimator"] == "biased"
            render = 20.0 + per_sample_ms * params["nc"][0] + noise_ms * rng.standard_normal()
            row = SimpleNamespace(id=2, seconds_per_frame=(render + 400.0) / 1e3,
                                  time_breakdown_ms={"render": render / 2,
                                                     "inference": render / 2,
                                                     "training": 400.0})
        return [(row, None)]

    return sweep


def test_fig5_slope_and_share(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    drawn: list[str] = []
    monkeypatch.setattr(nirc_fig5, "sweep", stub_sweep(0.1, 0.01))
    monkeypatch.setattr(nirc_fig5, "plot_panels", no_drawing(drawn))
    result, _paths = reproduce("nirc", "fig5", "quick", tmp_path, None, None)
    assert drawn == ["ms_per_frame", "render_ms"]
    [fit] = [p for p in result.points if p.series == "fit"]
    slope = fit.values["slope_ms"]
    assert slope.ci95[0] < 0.1 < slope.ci95[1]          # 0.1 ms per neural sample
    assert fit.values["share_of_pt"].value == pytest.approx(0.01, rel=0.2)
    assert [v.verdict for v in result.verdicts] == ["not comparable", "holds"]


@pytest.mark.parametrize(("per_sample_ms", "noise_ms", "pt_harness", "expected"), [
    (1.0, 0.01, 0.2, "does not hold"),    # planted: a neural sample costs 10 % of PT
    (0.2, 10.0, 0.2, "not comparable"),   # timings too noisy to tell
    (0.1, 0.01, 0.9, "not comparable"),   # PT's frame mostly outside kernels
])
def test_fig5_verdict_follows_the_timings(per_sample_ms: float, noise_ms: float,
                                          pt_harness: float, expected: str,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(nirc_fig5, "sweep", stub_sweep(per_sample_ms, noise_ms, pt_harness))
    verdicts = nirc_fig5.measure(Context(nirc_fig5.QUICK, None, None)).verdicts
    assert verdicts[1].verdict == expected
