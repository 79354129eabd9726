"""The `pt` method and the frame loop: reproducibility, parameters, timing protocol."""

from __future__ import annotations

import numpy as np
import pytest

from renderers.methods import MethodError, get_method, parse_params
from renderers.methods.base import FrameHooks
from renderers.timing import summarize


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


def test_timing_summary_excludes_the_warmup():
    frames = [{"render": 0.010}, {"render": 0.012}, {"render": 0.011}]
    summary = summarize(frames, warmup_s=2.5, whole_s=[0.011, 0.013, 0.012])
    assert summary["frame_median_s"] == pytest.approx(0.011)
    assert summary["frame_mean_s"] == pytest.approx(0.011)
    assert summary["warmup_s"] == 2.5
    assert summary["compile_s_estimate"] == pytest.approx(2.5 - 0.011)
    assert "sync" in summary["protocol"]


def test_a_nested_stage_is_not_counted_in_the_outer_one(mi):
    """The deferred cache inference runs inside mi.render: 'render' excludes it."""
    import time

    from renderers.timing import StageTimer

    timer = StageTimer()
    with timer.stage("render"):
        time.sleep(0.02)
        with timer.stage("inference"):
            time.sleep(0.05)
    assert timer.seconds["inference"] >= 0.05
    assert 0.02 <= timer.seconds["render"] < 0.05
