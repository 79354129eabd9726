"""The quality verdict: each degenerate input gives its code, the most severe wins,
and the metrics it makes meaningless are withheld."""

import numpy as np

from metrics.quality import (
    ERROR_METRICS,
    VERDICTS,
    RunFacts,
    assess,
    image_facts,
    withhold,
)


def facts(**overrides) -> RunFacts:
    values = {"pixels": 100, "renders": 2, "nonfinite_pixels": 0, "emitter_count": 1}
    return RunFacts(**{**values, **overrides})


def test_plain_run_is_ok() -> None:
    quality = assess(facts())
    assert (quality.verdict, quality.reasons, quality.withheld) == ("ok", (), ())


def test_nonfinite_below_the_limit_is_flagged_not_withheld() -> None:
    quality = assess(facts(nonfinite_pixels=1))  # 1 of 200 rendered pixels = 0.5 %
    assert quality.verdict == "nonfinite"
    assert quality.withheld == ()
    assert "0.5 %" in quality.reasons[0].message


def test_nonfinite_above_the_limit_withholds_every_error() -> None:
    quality = assess(facts(nonfinite_pixels=10))
    assert quality.verdict == "nonfinite" and quality.withheld == ERROR_METRICS
    assert "5 %" in quality.reasons[0].message


def test_no_emitter_is_the_most_severe_of_several_reasons() -> None:
    quality = assess(facts(emitter_count=0, reference_black_pixels=100, cache_steps=(0, 3)))
    assert quality.verdict == "no-emitter"
    assert [r.code for r in quality.reasons] == ["no-emitter", "degenerate-reference",
                                                 "untrained-cache"]
    assert set(quality.withheld) == set(ERROR_METRICS)


def test_degenerate_reference_keeps_the_absolute_error() -> None:
    quality = assess(facts(reference_black_pixels=100))
    assert quality.verdict == "degenerate-reference"
    assert "mse" not in quality.withheld and {"mrse", "rbias2", "flip"} <= set(quality.withheld)
    assert assess(facts(reference_black_pixels=99)).verdict == "ok"  # 99 % is not > 99 %


def test_negative_radiance_withholds_flip_and_untrained_cache_nothing() -> None:
    assert assess(facts(reference_negative_pixels=3)).withheld == ("flip",)
    # A signed estimator's negative pixels alone are not degenerate input.
    assert assess(facts(render_negative_pixels=3)).verdict == "ok"
    untrained = assess(facts(cache_steps=(0, 0), cache_skipped_steps=(4, 4)))
    assert untrained.verdict == "untrained-cache" and untrained.withheld == ()
    assert "2 of 2 caches" in untrained.reasons[0].message


def test_a_cache_below_its_minimum_steps_is_undertrained_and_withholds_nothing() -> None:
    short = assess(facts(cache_steps=(12, 150), cache_min_steps=(100, 100)))
    assert short.verdict == "undertrained-cache" and short.withheld == ()
    assert "1 of 2 caches took fewer successful training steps (12)" in short.reasons[0].message
    assert assess(facts(cache_steps=(100, 150), cache_min_steps=(100, 100))).verdict == "ok"
    # A cache with no step at all is untrained, and only that.
    none = assess(facts(cache_steps=(0, 150), cache_min_steps=(100, 100)))
    assert [r.code for r in none.reasons] == ["untrained-cache"]


def test_every_code_has_a_distinct_severity() -> None:
    assert len({v.severity for v in VERDICTS.values()}) == len(VERDICTS)


def test_image_facts_and_withhold() -> None:
    image = np.zeros((4, 4, 3), np.float32)
    image[0, 0] = np.nan
    image[0, 1] = [-1.0, 2.0, 2.0]
    image[0, 2] = 1.0
    assert image_facts(image) == {"pixels": 16, "nonfinite": 1, "black": 13, "negative": 1}
    values = {"mrse_mean": 1.0, "mrse_ci95": [0, 2], "mse_mean": 3.0, "rbias2_raw": 1.0,
              "noise_floor": 0.1, "flip_hdr_mean": 0.2, "flip_exposures": [0, 1], "k": 2}
    assert withhold(values, ["mrse", "rbias2", "flip"]) == {
        **values, "mrse_mean": None, "mrse_ci95": None, "rbias2_raw": None,
        "noise_floor": None, "flip_hdr_mean": None}
    assert withhold(values, []) == values


def test_negative_pixels_are_not_black() -> None:
    image = np.full((4, 4, 3), -1.0, np.float32)
    assert image_facts(image)["black"] == 0 and image_facts(image)["negative"] == 16


def test_an_overflowing_reference_variance_is_named() -> None:
    quality = assess(facts(reference_nonfinite_pixels=100,
                           reference_variance_nonfinite_pixels=100))
    assert quality.verdict == "nonfinite" and set(quality.withheld) == set(ERROR_METRICS)
    message = quality.reasons[0].message
    assert message.startswith("100 of 100 reference pixels (in 100 of them the reference's "
                              "variance overflowed")


def test_an_untrained_cache_says_why() -> None:
    skipped = assess(facts(cache_steps=(0, 5), cache_skipped_steps=(12, 3),
                           cache_records=(900, 900)))
    assert "all 12 steps they tried were skipped because the loss" in \
        skipped.reasons[0].message
    starved = assess(facts(cache_steps=(0,), cache_skipped_steps=(0,), cache_records=(0,),
                           cache_dropped_nonfinite=(40,)))
    assert "no usable training record (40 dropped as NaN or infinite)" in \
        starved.reasons[0].message
