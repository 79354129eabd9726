"""`reproduce nirc fig10` from stubbed stored animated runs (the per-frame errors
themselves are tested in tests/service/test_animated_jobs.py): the first frame from
which a cache stays below its PT, with its bootstrap interval, the table and PNG, and
verdicts that turn with the numbers (a cache never below is 'does not hold', one
crossing late 'not comparable')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from jobs.reproduce import nirc_fig10
from jobs.reproduce.run import reproduce
from metrics.recovery import frame_error_curve

FRAMES, SEEDS = nirc_fig10.QUICK.frames, nirc_fig10.QUICK.seeds


def _run(expected: np.ndarray, seed: int) -> Any:
    """A stored animated run whose seeds' errors scatter 2 % about ``expected``."""
    rng = np.random.default_rng(seed)
    errors = expected * rng.lognormal(0.0, 0.02, size=(SEEDS, FRAMES))
    curve = frame_error_curve(errors)
    return SimpleNamespace(
        id=seed, timings={"seconds_per_frame": 0.01},
        metrics={"animation": {"frame_mrse": curve, "frame_flip": curve,
                               "flicker": {"mean": 0.1, "low": 0.09, "high": 0.11}}},
        seed_results=[SimpleNamespace(metrics={"convergence": {"frame_mrse": row.tolist()}})
                      for row in errors])


#: PT's expected error per frame, and the caches': one falling below it from frame 8
#: (0.5 + 2.5 * 5^(-f / 7.5): 1.058 at frame 7, 0.949 at 8), one above it throughout,
#: one equal to it (its crossing is the seeds' chance).
PT = np.ones(FRAMES)
CACHES = {"NIRC biased": 0.5 + 2.5 * 5.0 ** (-np.arange(FRAMES) / 7.5),
          "NRC": np.full(FRAMES, 1.3), "NIRC unbiased": PT}


def render_series(ctx: Any, method: str, params: dict[str, Any], spp: int) -> Any:
    series = next(s for s, m, p, n in nirc_fig10.SERIES if (m, p, n) == (method, params, spp))
    return _run(CACHES.get(series, PT), seed=len(series))


def test_fig10_finds_the_crossing_and_draws_the_curves(monkeypatch: pytest.MonkeyPatch,
                                                       tmp_path: Path) -> None:
    monkeypatch.setattr(nirc_fig10, "render_series", render_series)
    result, paths = reproduce("nirc", "fig10", "quick", tmp_path, None, None)
    assert paths["figure"].read_bytes()[:4] == b"\x89PNG"
    summary = {p.series: p.values for p in result.points if p.x is None}
    first = summary["NIRC biased"]["first_below"]
    assert first.value == 8 and first.ci95[0] <= 8 <= first.ci95[1] <= 9
    assert summary["NRC"]["first_below"].value is None
    assert "first_below" not in summary["PT 1 spp"]
    assert [v.verdict for v in result.verdicts] == ["holds", "does not hold", "not comparable"]
    assert len([p for p in result.points if p.x is not None]) == len(nirc_fig10.SERIES) * FRAMES
    assert "**holds**" in paths["markdown"].read_text()


def test_first_below_is_the_frame_after_the_last_one_above() -> None:
    pt = np.ones((2, 6))
    cache = np.array([[3.0, 0.5, 2.0, 0.9, 0.8, 0.7]] * 2)
    assert nirc_fig10.first_below(cache, pt) == 3     # frame 1 dips, frame 2 is above
    assert nirc_fig10.first_below(pt * 0.5, pt) == 0
    assert nirc_fig10.first_below(cache[:, ::-1], pt) is None   # the last frame is above
