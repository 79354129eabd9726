"""`reproduce nirc fig14` from stubbed runs of synthetic seed images: the variance maps of
PT and MLMC by smooth and edge pixels, the diverging map's PNG, and a verdict that turns
with the images (planted MLMC noisier in the smooth pixels 'does not hold', equal noise
'not comparable')."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from jobs.reproduce import nirc_fig14
from jobs.reproduce.registry import Context
from jobs.reproduce.run import reproduce

SIZE = 16
SEEDS = 8
PT, NIRC = 1, 2


def reference() -> np.ndarray:
    """A lit square on a dim floor, a sky band of zero variance on top."""
    ref = np.full((SIZE, SIZE, 3), 0.2, dtype=np.float32)
    ref[5:12, 4:12] = 1.0
    return ref


def renders(sigma_smooth: float, sigma_edge: float, seed: int) -> list[np.ndarray]:
    """SEEDS renders: the reference plus Gaussian noise of relative deviation
    ``sigma_smooth`` in the smooth pixels and ``sigma_edge`` at the square's border; the
    top two rows (the sky) exact."""
    ref = reference()
    edges = nirc_fig14.edge_mask(ref, np.ones((SIZE, SIZE), dtype=bool))
    sigma = np.where(edges, sigma_edge, sigma_smooth)[..., None] * ref
    sigma[:2] = 0.0
    rng = np.random.default_rng(seed)
    return [ref + sigma * rng.standard_normal(ref.shape).astype(np.float32)
            for _ in range(SEEDS)]


def stub(monkeypatch: pytest.MonkeyPatch, nirc_smooth: float, nirc_edge: float) -> None:
    """PT of relative deviation 0.3 everywhere; MLMC as given."""
    monkeypatch.setattr(nirc_fig14, "BOOTSTRAP_DRAWS", 200)   # half the cost, same verdicts
    images = {PT: renders(0.3, 0.3, 1), NIRC: renders(nirc_smooth, nirc_edge, 2)}

    def sweep(ctx: Any, scene: str, method: str, parameter: str, values: list[Any],
              params: dict[str, Any], max_depth: int = -1) -> list[tuple[Any, Any]]:
        assert scene == "sky" and max_depth == nirc_fig14.MAX_DEPTH
        run = SimpleNamespace(id=PT if method == "pt" else NIRC)
        assert method == "pt" or params["estimator"] == "unbiased"
        return [(run, run)]

    monkeypatch.setattr(nirc_fig14, "sweep", sweep)
    monkeypatch.setattr(nirc_fig14, "seed_images",
                        lambda _ctx, run: (images[run.id], reference()))


def test_fig14_regions_and_the_png(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    stub(monkeypatch, nirc_smooth=0.1, nirc_edge=0.5)
    result, paths = reproduce("nirc", "fig14", "quick", tmp_path, None, None)
    assert paths["figure"].read_bytes()[:4] == b"\x89PNG"
    by_region = {p.series: p.values for p in result.points}
    assert by_region["smooth pixels"]["variance_ratio"].ci95[0] > 1.0
    assert by_region["edge pixels"]["variance_ratio"].ci95[1] < 1.0
    assert result.verdicts[0].verdict == "holds"
    # The sky rows have no variance in either method: left out of every region.
    assert np.isnan(result.images["difference"][:2]).all()


@pytest.mark.parametrize(("nirc_smooth", "nirc_edge", "expected"), [
    (0.6, 0.1, "does not hold"),     # planted: MLMC worse in the smooth pixels
    (0.3, 0.3, "not comparable"),    # the same noise as PT
])
def test_fig14_verdict_follows_the_images(nirc_smooth: float, nirc_edge: float,
                                          expected: str,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    stub(monkeypatch, nirc_smooth, nirc_edge)
    [verdict] = nirc_fig14.measure(Context(nirc_fig14.QUICK, None, None)).verdicts
    assert verdict.verdict == expected
