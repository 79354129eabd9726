"""The training budget of the caching methods, and the per-frame time breakdown.

The rule (renderers/methods/budget.py): records per frame scale with the pixel
count between a floor and the papers' 4 x 16384, the 'paper' mode keeps 4 x
16384 at every size, and a frame traces enough paths to hold its records. A
small render must train exactly that budget, and its time breakdown (NIRC
paper, Table 1) must add up to the whole frame.
"""

from __future__ import annotations

import math

import pytest

from renderers.caches import nirc_config, nrc_config
from renderers.methods import MethodError, get_method, parse_params
from renderers.methods.budget import (
    MIN_RECORDS,
    PAPER_BATCH,
    PAPER_PIXELS,
    PAPER_STEPS,
    RECORD_FRACTION,
    frame_training_budget,
)

SIZES = [32 * 32, 128 * 128, 256 * 256, 512 * 512, 1000 * 1000, PAPER_PIXELS, 3840 * 2160]


def _budget(pixels: int, method: str = "nirc", **values):
    """The budget of a frame of ``pixels`` for ``method`` with parameters ``values``."""
    params = parse_params(method, values)
    config = (nirc_config if method == "nirc" else nrc_config)(**params.cache)
    return frame_training_budget(pixels, params, config)


def test_the_default_fraction_is_the_papers_records_over_a_1080p_frame():
    assert PAPER_STEPS * PAPER_BATCH == 65536
    assert RECORD_FRACTION == pytest.approx(65536 / 2073600)
    assert 0.0315 < RECORD_FRACTION < 0.0317


@pytest.mark.parametrize("method", ["nirc", "nrc"])
def test_scaled_records_follow_the_pixel_count_between_floor_and_cap(method):
    for pixels in SIZES:
        budget = _budget(pixels, method)
        wanted = max(MIN_RECORDS, RECORD_FRACTION * pixels)
        assert budget.mode == "scaled" and budget.steps == PAPER_STEPS
        assert budget.records == min(PAPER_STEPS * PAPER_BATCH,
                                     PAPER_STEPS * math.ceil(math.ceil(wanted) / PAPER_STEPS))
    # Between floor and cap, 4x the pixels train 4x the records (up to rounding to the steps).
    mid = _budget(512 * 512).records, _budget(1024 * 1024).records
    assert mid[1] == pytest.approx(4 * mid[0], rel=1e-3)
    assert _budget(PAPER_PIXELS).records == 65536                  # the papers' frame
    assert _budget(32 * 32).records == MIN_RECORDS                 # the floor
    assert _budget(128 * 128).batch_size == MIN_RECORDS // PAPER_STEPS
    assert _budget(3840 * 2160).batch_size == PAPER_BATCH          # the cap


def test_paper_mode_trains_4_x_16384_at_every_size():
    for pixels in SIZES:
        budget = _budget(pixels, training_budget="paper")
        assert (budget.mode, budget.steps, budget.batch_size) == ("paper", 4, 16384)


def test_floor_fraction_and_cache_batch_are_parameters():
    assert _budget(32 * 32, min_train_records=256).batch_size == 64
    assert _budget(128 * 128, train_record_fraction=1.0).records == 16384
    # A smaller cache batch caps the scaled batch (as in the fast test settings).
    assert _budget(PAPER_PIXELS, cache={"batch_size": 1024}).records == 4096
    assert _budget(32 * 32, cache={"batch_size": 256}).records == 1024
    # No training: no steps, whatever the mode.
    for mode in ("scaled", "paper"):
        no_steps = _budget(PAPER_PIXELS, training_budget=mode, cache={"steps_per_frame": 0})
        assert no_steps.records == 0


@pytest.mark.parametrize("mode", ["scaled", "paper"])
def test_a_frame_traces_a_record_slot_for_every_record_drawn(mode):
    for pixels in SIZES:
        for record_depth in (1, 3):
            budget = _budget(pixels, training_budget=mode, record_depth=record_depth)
            assert budget.paths * record_depth >= budget.records
            assert budget.paths >= max(4096, math.ceil(0.03 * pixels))
    # At the papers' frame the training paths are the papers' 3 % of the pixels.
    assert _budget(PAPER_PIXELS).paths == math.ceil(0.03 * PAPER_PIXELS)


@pytest.mark.parametrize("params, field", [
    ({"training_budget": "huge"}, "training_budget"),
    ({"train_record_fraction": 0.0}, "train_record_fraction"),
    ({"train_record_fraction": 100.0}, "train_record_fraction"),
    ({"min_train_records": 0}, "min_train_records"),
    ({"training_budget": "paper", "min_train_records": 1024}, "min_train_records"),
    ({"training_budget": "paper", "train_record_fraction": 0.1}, "train_record_fraction"),
])
def test_invalid_budget_parameters_name_the_field(params, field):
    with pytest.raises(MethodError, match=field):
        parse_params("nirc", params)


def test_dumped_parameters_validate_again():
    for mode in ("scaled", "paper"):
        params = parse_params("nrc", {"training_budget": mode})
        assert parse_params("nrc", params.model_dump(mode="json")) == params


@pytest.fixture(scope="module")
def scene(mi):
    from renderers.scenes import load_scene

    return load_scene("cornell-box", 32)


@pytest.mark.parametrize("method", ["nirc", "nrc"])
def test_a_render_trains_its_budget_and_breaks_its_frame_time_down(scene, method):
    frames, pretrain = 5, 1
    params = parse_params(method, {"max_depth": 6, "pretrain_frames": pretrain})
    out = get_method(method).render(scene, params, seed_parts=("budget", method), spp=1,
                                    frames=frames)
    budget = out.method_stats["caches"]["cache"]["per_frame"]
    assert budget == {"mode": "scaled", "paths": 4096, "steps": 4, "batch_size": 1024,
                      "records": 4096}
    stats = out.method_stats["cache_stats"]
    trained_frames = pretrain + 1 + frames       # pre-training, warm-up, timed frames
    assert stats["skipped_steps"] == 0 and stats["steps"] == 4 * trained_frames
    assert stats["records_trained"] == budget["records"] * trained_frames
    assert len(out.method_stats["loss_history"]) == stats["steps"]

    result = out.timings["breakdown"]
    parts = result["parts_s"]
    assert {"render", "training_paths", "training", "other"} <= set(parts)
    assert all(seconds >= 0.0 for seconds in parts.values())
    assert result["inference_in_render"] == ("inference" not in parts)
    # The parts of the median frame add up to its whole time; its stages to the frame time.
    assert sum(parts.values()) == pytest.approx(result["frame_s"])
    assert sum(parts.values()) - parts["other"] == pytest.approx(out.timings["frame_median_s"])
