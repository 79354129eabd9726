"""Renders that differ only in their policy share one pre-fill per seed within
``prefills_shared`` (renderers/methods/grid_cache.py, ``prefilled``; a reproduced
figure measures within it): a render that reuses the pre-fill gives the image it gives
with a pre-fill of its own, a render whose pre-fill would differ (another roulette
survival) pre-fills anew, and outside the scope nothing is kept. Planted: a key that
leaves the survival out reuses the other survival's grid, and the image shows it.

Seven tiny renders (8x8, a pre-fill of at most 12 passes, one frame, no warm-up)."""

from __future__ import annotations

import numpy as np
import pytest

from renderers.methods import get_method, parse_params
from renderers.methods.base import FrameHooks

SEED_PARTS = ("prefill-reuse", 0)
POLICIES = {"var-bound": {"threshold": 0.1, "relative": False}, "area-spread": {"c": 0.01}}


@pytest.fixture(scope="module")
def scene(mi):
    from renderers.scenes import load_scene

    return load_scene("cornell-box", 8)


def _render(scene, policy: str, **changes) -> tuple[np.ndarray, bool]:
    """(image, whether the pre-fill was reused) of ``policy`` on ``scene``; the params
    are in the seed parts as the executors put them."""
    params = parse_params("grid-cache", {"termination": policy,
                                         "termination_params": POLICIES[policy],
                                         "prefill_frames": 12, **changes})
    output = get_method("grid-cache").render(
        scene, params, seed_parts=(*SEED_PARTS, params.model_dump(mode="json")), spp=1,
        frames=1, hooks=FrameHooks(kernel_every=0, warmup=False))
    return np.asarray(output.accumulated), output.method_stats["prefill_reused"]


def test_a_reused_prefill_renders_as_its_own_and_another_survival_prefills_anew(
        scene, monkeypatch):
    from renderers.methods import grid_cache

    with grid_cache.prefills_shared():
        own, reused = _render(scene, "area-spread")
        assert not reused
        grid_cache._PREFILLS.clear()
        _render(scene, "var-bound")
        shared, reused = _render(scene, "area-spread")
        assert reused
        np.testing.assert_array_equal(shared, own)
        own_half, reused = _render(scene, "area-spread", rr_survival=0.5)
        assert not reused
        # Planted: the survival counted as the policy's, so left out of the key.
        grid_cache._PREFILLS.clear()
        with monkeypatch.context() as planted:
            planted.setattr(grid_cache, "POLICY_FIELDS",
                            grid_cache.POLICY_FIELDS | {"rr_survival"})
            _render(scene, "var-bound")
            wrong, reused = _render(scene, "area-spread", rr_survival=0.5)
        assert reused and not np.array_equal(wrong, own_half)
    assert not _render(scene, "area-spread")[1]   # nothing is kept outside the scope
