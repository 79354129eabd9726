"""Recovery after a change (metrics.recovery) on synthetic per-frame errors whose
recovery frame is known: the frame count is exact (a planted off-by-one is rejected),
the bootstrap interval and the per-frame Student-t intervals cover the truth."""

from __future__ import annotations

import numpy as np
import pytest

import metrics.recovery as recovery_module
from metrics.recovery import frame_error_curve, recoveries, recovery

CHANGE, FRAMES, SEEDS = 8, 24, 8
STEADY = 0.2


def expected_curve(excess: float, decay_frames: float) -> np.ndarray:
    """E[error] per frame: steady before the change, after it steady * (1 + excess *
    exp(-j / decay_frames)) at frame CHANGE + j."""
    curve = np.full(FRAMES, STEADY)
    after = np.arange(FRAMES - CHANGE)
    curve[CHANGE:] = STEADY * (1 + excess * np.exp(-after / decay_frames))
    return curve


def true_recovery(curve: np.ndarray) -> int:
    """The definition, written out: the first j after which every frame before the
    steady window is within 10 % of the window's mean."""
    window = FRAMES - 4
    steady = curve[window:].mean()
    within = curve[CHANGE:window] <= 1.1 * steady
    return next(j for j in range(window - CHANGE + 1) if within[j:].all())


def seed_errors(curve: np.ndarray, noise: float, rng: np.random.Generator) -> np.ndarray:
    """(seeds, frames) errors: the curve times independent log-normal noise of mean 1."""
    return curve * rng.lognormal(-noise**2 / 2, noise, size=(SEEDS, FRAMES))


def test_a_sharp_recovery_is_counted_exactly_and_an_off_by_one_is_rejected(monkeypatch):
    # Four frames 5x to 2x the steady error, then steady: recovered 4 frames after.
    curve = np.full(FRAMES, STEADY)
    curve[CHANGE:CHANGE + 4] = STEADY * np.array([5.0, 4.0, 3.0, 2.0])
    errors = seed_errors(curve, 0.01, np.random.default_rng(1))
    assert true_recovery(curve) == 4
    found = recovery(errors, CHANGE, FRAMES - 1, draws=200)
    assert found.frames == 4 and found.low == found.high == 4
    assert found.error_at_change == pytest.approx(5 * STEADY, rel=0.02)
    assert found.error_before == pytest.approx(STEADY, rel=0.02)
    assert not found.within_window
    # Planted: counting from the frame before the change (one frame more).
    original = recovery_module.recovery_frames
    monkeypatch.setattr(recovery_module, "recovery_frames",
                        lambda *args: original(*args) + 1)
    assert recovery(errors, CHANGE, FRAMES - 1, draws=200).frames != 4


def test_each_change_is_measured_on_its_own_segment():
    curve = np.full(FRAMES, STEADY)
    curve[6:8] = 3 * STEADY      # change at 6: recovered after 2 frames
    curve[14] = 3 * STEADY       # change at 14: after 1
    errors = seed_errors(curve, 0.01, np.random.default_rng(2))
    found = recoveries(errors, [6, 14, 22], draws=100)
    assert [(f["change_frame"], f.get("frames")) for f in found] == [(6, 2), (14, 1), (22, None)]
    assert "too short" in found[2]["note"]


@pytest.mark.parametrize("planted", [False, True])
def test_the_intervals_cover_the_truth(planted):
    """40 replications of 8 seeds each on a slow recovery whose count varies with the
    noise: the bootstrap interval of the recovery time holds the true count in at
    least 80 % of them (nominal 95 %, discrete statistic), each frame's t-interval its
    expected error in at least 85 % (nominal 95 %; binomial 1e-4 tails). Planted:
    intervals from the first seed's errors alone (too narrow) are rejected."""
    rng = np.random.default_rng(3 + planted)
    curve = expected_curve(excess=3.0, decay_frames=1.6)
    truth = true_recovery(curve)
    replications, covered, frame_covered = 40, 0, 0
    for _ in range(replications):
        errors = seed_errors(curve, 0.1, rng)
        sample = errors[:1].repeat(SEEDS, axis=0) + 1e-9 * rng.standard_normal(
            (SEEDS, FRAMES)) if planted else errors
        found = recovery(sample, CHANGE, FRAMES - 1, draws=300, seed=int(rng.integers(1 << 30)))
        covered += found.low <= truth <= found.high
        band = frame_error_curve(sample)
        frame_covered += int(np.sum((np.array(band["low"]) <= curve)
                                    & (curve <= np.array(band["high"]))))
    holds = covered >= 0.8 * replications and frame_covered >= 0.85 * replications * FRAMES
    assert holds != planted, (covered, frame_covered)
