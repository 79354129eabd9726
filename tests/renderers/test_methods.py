"""The `pt` method and the frame loop: reproducibility, parameters, timing protocol."""

from __future__ import annotations

import numpy as np
import pytest

from renderers.methods import MethodError, get_method, parse_params
from renderers.methods.base import FrameHooks


@pytest.fixture(scope="module")
def scene(mi):
    from renderers.scenes import load_scene

    return load_scene("cornell-box", 16)


def _render(scene, seed_index, frames=2, **params):
    method = get_method("pt")
    p = parse_params("pt", params)
    return method.render(scene, p, seed_parts=(scene.fingerprint, "pt", p.model_dump(), seed_index),
                         spp=1, frames=frames, hooks=FrameHooks(keep_frames=True))


def test_render_is_reproducible_from_its_seed(scene):
    a, b = _render(scene, 0), _render(scene, 0)
    np.testing.assert_array_equal(a.accumulated, b.accumulated)
    assert not np.array_equal(a.accumulated, _render(scene, 1).accumulated)


def test_frames_use_independent_seeds_and_accumulate_their_mean(scene):
    out = _render(scene, 3, frames=3)
    assert len(out.frames) == 3
    assert not np.array_equal(out.frames[0], out.frames[1])
    np.testing.assert_allclose(out.accumulated, np.mean(out.frames, axis=0), rtol=1e-5, atol=1e-6)


def test_outputs_carry_timings_and_path_statistics(scene):
    out = _render(scene, 0, frames=3, max_depth=8)
    assert out.timings["frames"] == 3 and len(out.timings["per_frame"]) == 3
    assert out.timings["stages"]["render"]["mean_s"] > 0
    assert out.timings["warmup_s"] > 0
    # Camera rays hit the box, NEE needs at least one vertex, roulette caps nothing at depth 8.
    assert 1.0 <= out.path_stats["avg_path_vertices"] <= 8.0


def test_max_depth_bounds_the_path_length(scene):
    assert _render(scene, 0, max_depth=2).path_stats["avg_path_vertices"] <= 2.0


@pytest.mark.parametrize("params, field", [
    ({"max_depth": 0}, "max_depth"),
    ({"max_depth": -2}, "max_depth"),
    ({"rr_survival": 0.0}, "rr_survival"),
    ({"rr_mode": "magic"}, "rr_mode"),
    ({"bogus": 1}, "bogus"),
])
def test_invalid_parameters_name_the_field(params, field):
    with pytest.raises(MethodError, match=field):
        parse_params("pt", params)


def test_unknown_method_lists_the_known_ones():
    with pytest.raises(MethodError, match="pt"):
        get_method("nope")
