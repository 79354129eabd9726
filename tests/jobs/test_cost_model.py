"""The per-stage cost model on synthetic timings with a known a and b."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

from jobs.costs.cost_model import Probe, fit_line, measure, probes_for

FLOOR, FRACTION = 4096, 0.0316


def test_a_fit_recovers_a_known_line_within_its_intervals():
    rng = np.random.default_rng(7)
    sizes = np.repeat([4096.0, 16384.0, 65536.0], 3)
    fit = fit_line(sizes, 0.004 + 2e-7 * sizes + rng.normal(0, 2e-4, sizes.size))
    assert fit.intercept_ci[0] <= 0.004 <= fit.intercept_ci[1]
    assert fit.slope_ci[0] <= 2e-7 <= fit.slope_ci[1]
    at = fit.predict(1e5)
    assert at.ci[0] <= 0.004 + 2e-7 * 1e5 <= at.ci[1]


#: A probe set like the default one (64², 128², 256², 3 rounds) of a stage costing
#: 0.4 ms + 0.3 us per pixel sample, timed with noise of 5 % of the frame's time.
TRUE_A, TRUE_B, RELATIVE_NOISE = 4e-4, 3e-7, 0.05
PROBE_SIZES = np.repeat([4096.0, 16384.0, 65536.0], 3)
FAR = 1920 * 1080


def noisy_probes(rng: np.random.Generator) -> np.ndarray:
    truth = TRUE_A + TRUE_B * PROBE_SIZES
    return truth * (1 + rng.normal(0, RELATIVE_NOISE, truth.size))


def test_the_intervals_cover_the_truth_as_often_as_they_claim():
    """400 fits of probes whose spread grows with their size: the 95 % intervals of a,
    b and of a prediction far beyond the probes (1080p) each cover the truth in 95 %
    of them (binomial 99.9 % bounds)."""
    rng = np.random.default_rng(11)
    trials = 400
    hits = np.zeros(3)
    for _ in range(trials):
        fit = fit_line(PROBE_SIZES, noisy_probes(rng))
        far = fit.predict(FAR)
        hits += [fit.intercept_ci[0] <= TRUE_A <= fit.intercept_ci[1],
                 fit.slope_ci[0] <= TRUE_B <= fit.slope_ci[1],
                 far.ci[0] <= TRUE_A + TRUE_B * FAR <= far.ci[1]]
    low, high = stats.binom.ppf([0.0005, 0.9995], trials, 0.95)
    assert np.all((low <= hits) & (hits <= high)), hits


def test_the_noisy_largest_probe_pulls_an_unweighted_fit_not_the_weighted_one():
    """The planted mistake: ordinary least squares (linregress) on the same probes lets
    the 256² probe's noise, 12x that of 64² here in seconds, decide the line: its intercept
    errs about twice as much, and its slope interval covers the truth far less often
    than the 95 % it claims (about 80 %)."""
    rng = np.random.default_rng(12)
    trials = 400
    seconds = np.array([noisy_probes(rng) for _ in range(trials)])
    weighted_a = [fit_line(PROBE_SIZES, row).intercept - TRUE_A for row in seconds]
    # Ordinary least squares of every trial at once (what linregress computes).
    centred = PROBE_SIZES - PROBE_SIZES.mean()
    plain_b = seconds @ centred / (centred @ centred)
    plain_a = seconds.mean(axis=1) - plain_b * PROBE_SIZES.mean() - TRUE_A
    residuals = seconds - (plain_a + TRUE_A)[:, None] - plain_b[:, None] * PROBE_SIZES
    plain_se_b = np.sqrt((residuals ** 2).sum(axis=1) / (PROBE_SIZES.size - 2)
                         / (centred @ centred))
    plain_hits = np.sum(np.abs(plain_b - TRUE_B)
                        <= stats.t.ppf(0.975, PROBE_SIZES.size - 2) * plain_se_b)
    rms = lambda errors: float(np.sqrt(np.mean(np.square(errors))))  # noqa: E731
    assert rms(weighted_a) < 0.7 * rms(plain_a), (rms(weighted_a), rms(plain_a))
    assert plain_hits < stats.binom.ppf(0.0005, trials, 0.95), plain_hits


def test_a_stage_of_one_size_is_a_constant_that_projects_only_to_that_size():
    fit = fit_line([1.0] * 4, [0.010, 0.011, 0.012, 0.011])
    assert fit.slope is None and fit.intercept == pytest.approx(0.011)
    assert fit.predict(1.0).value == pytest.approx(0.011)
    assert fit.predict(2.0).value is None and "held" in fit.predict(2.0).note


def test_bad_samples_are_refused():
    with pytest.raises(ValueError, match="two samples"):
        fit_line([1.0], [1.0])
    with pytest.raises(ValueError, match="non-finite"):
        fit_line([1.0, 2.0, 3.0], [1.0, float("nan"), 2.0])


# ---- A synthetic method: render a + b P, training a + b max(floor, fraction P) ----
RENDER = (0.003, 40e-9)       # s, s per pixel sample
TRAINING = (0.020, 2e-6)      # s, s per record
OTHER = (0.001, 0.0)


def records(params: SimpleNamespace, pixels: int) -> int:
    return min(max(params.floor, math.ceil(FRACTION * pixels)), 65536)


METHOD = SimpleNamespace(
    name="synthetic",
    stage_sizes=lambda params, pixels, _spp: {"training": records(params, pixels)},
    scale_floors=lambda params, factor: SimpleNamespace(floor=round(params.floor * factor)))


HD_RECORDS = records(SimpleNamespace(floor=FLOOR), 1920 * 1080)
HD_TRUTH = RENDER[0] + RENDER[1] * 1920 * 1080 + TRAINING[0] + TRAINING[1] * HD_RECORDS


def synthetic_render(noise: float, seed: int = 3):
    rng = np.random.default_rng(seed)

    def render(resolution: int, params: SimpleNamespace, spp: int) -> dict:
        pixels = resolution * resolution * spp

        def jitter(seconds: float) -> float:
            return seconds * (1 + rng.normal(0, noise))
        frames = []
        for _ in range(3):
            stages = {"render": jitter(RENDER[0] + RENDER[1] * pixels),
                      "training": jitter(TRAINING[0] + TRAINING[1] * records(params, pixels))}
            whole = sum(stages.values()) + OTHER[0]
            kernel = {name: 0.8 * value for name, value in stages.items()}
            frames.append({"stages": stages, "whole_s": whole, "kernel_s": kernel,
                           "launches": dict.fromkeys(stages, 3)})
        return {"frames_detail": frames, "load": None}
    return render


def test_a_floored_stage_is_measured_by_scaling_its_floor_and_projected_by_its_rule():
    params = SimpleNamespace(floor=FLOOR)
    assert probes_for(METHOD, (64, 128, 256), (1, 4, 16)) == [
        Probe(64), Probe(128), Probe(256), Probe(64, 4), Probe(64, 16)]
    model = measure(METHOD, params, 1, "test-device", synthetic_render(0.01), rounds=3)
    training = model.stages["training"].wall
    assert training.slope_ci[0] <= TRAINING[1] <= training.slope_ci[1]
    assert training.intercept_ci[0] <= TRAINING[0] <= training.intercept_ci[1]
    render = model.stages["render"].wall
    assert render.slope_ci[0] <= RENDER[1] <= render.slope_ci[1]
    assert model.stages["training"].unit.startswith("units") and not model.flags

    hd = model.project(1920, 1080)
    assert hd.frame_ci[0] <= HD_TRUTH <= hd.frame_ci[1]
    stage = {s.stage: s for s in hd.stages}
    assert stage["training"].size == HD_RECORDS == 65526   # 16x the floor
    assert "from test-device" in hd.label and any("extrapolated" in n for n in hd.notes)
    assert hd.harness_share == pytest.approx(1 - 0.8 * hd.frame_s / (hd.frame_s + hd.other_s),
                                             rel=0.05)
    # Below the floor the rule holds the training at 4096 records.
    small = {s.stage: s for s in model.project(128, 128).stages}["training"]
    assert small.size == FLOOR
    assert small.wall.value == pytest.approx(TRAINING[0] + TRAINING[1] * FLOOR, rel=0.05)


def test_without_the_floor_rule_the_projection_would_be_far_off():
    """The planted mistake the rule prevents: a straight line in pixels through probes at
    which the training sits at its floor has no slope, and misses 1080p's 16x records."""
    params = SimpleNamespace(floor=FLOOR)
    naive = SimpleNamespace(name="naive", stage_sizes=lambda *_: {}, scale_floors=None)
    model = measure(naive, params, 1, "test-device", synthetic_render(0.01), rounds=3)
    hd = model.project(1920, 1080)
    assert hd.frame_s < 0.8 * HD_TRUTH and not hd.frame_ci[0] <= HD_TRUTH <= hd.frame_ci[1]


def test_probes_that_disagree_between_rounds_are_flagged():
    params = SimpleNamespace(floor=FLOOR)
    model = measure(METHOD, params, 1, "test-device", synthetic_render(0.3, seed=5), rounds=3)
    assert any("spread" in flag for flag in model.flags)
    assert any("spread" in note for note in model.project(1920, 1080).notes)
