"""Flicker (jobs.protocol.flicker) on synthetic frames whose statistics are known: the
static region keeps pixels whose references differ by noise only and drops those that
changed, and a run's flicker interval covers the expected frame-to-frame difference of
independent frames; a cache whose prediction drifts in the static region is told apart,
and a difference taken over a changed region (a planted mask of all pixels) is not
flicker."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from jobs.protocol.flicker import STATIC_Z, frame_flicker, run_flicker, seed_flicker, static_mask

SIZE, FRAMES, SEEDS, EPS = 16, 8, 16, 0.01
SIGMA = 0.05          # a frame's per-pixel noise (standard deviation)
REF_SPP = 256         # the references' noise is SIGMA / sqrt(REF_SPP)


def _reference(mean: np.ndarray, rng: np.random.Generator) -> SimpleNamespace:
    variance = np.full_like(mean, SIGMA**2 / REF_SPP)
    return SimpleNamespace(mean=mean + rng.normal(0.0, np.sqrt(variance)), variance=variance)


def test_the_static_region_keeps_noise_and_drops_a_change():
    rng = np.random.default_rng(1)
    truth = rng.uniform(0.2, 1.0, size=(SIZE, SIZE, 3))
    changed = truth.copy()
    changed[:4] *= 4.0      # a light brightened over the top rows
    a, b = _reference(truth, rng), _reference(changed, rng)
    mask = static_mask(a, b)
    assert not mask[:4].any()
    # Noise alone: each channel within Z sigma with probability 0.9973 (three channels).
    assert mask[4:].mean() > 0.97
    assert static_mask(a, a).all()


def _run(drift: float, all_pixels: bool, seed: int) -> tuple[dict, float]:
    """A run of SEEDS seeds of FRAMES frames on a scene whose top rows change at every
    frame: frames are the truth plus noise plus a prediction moving by ``drift`` per
    frame; returns the run's flicker and its expectation over the static rows."""
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0.2, 1.0, size=(SIZE, SIZE, 3))
    states = [truth.copy() for _ in range(FRAMES)]
    for frame, state in enumerate(states):
        state[:4] *= 1.0 + frame     # the moving part
    references = [_reference(state, rng) for state in states]
    masks = [np.ones((SIZE, SIZE), bool) if all_pixels else static_mask(p, c)
             for p, c in zip(references, references[1:], strict=False)]
    per_seed = []
    for _ in range(SEEDS):
        frames = [state + drift * index + rng.normal(0.0, SIGMA, state.shape)
                  for index, state in enumerate(states)]
        per_seed.append(seed_flicker([
            frame_flicker(frames[f - 1], frames[f], references[f].mean, masks[f - 1], EPS)
            for f in range(1, FRAMES)]))
    static = truth[4:]
    expected = float(np.mean((2 * SIGMA**2 + drift**2) / (static**2 + EPS)))
    return run_flicker(per_seed, [float(m.mean()) for m in masks]), expected


def test_the_runs_flicker_covers_independent_frames_and_tells_a_drift_apart():
    steady, expected = _run(drift=0.0, all_pixels=False, seed=2)
    assert steady["low"] <= expected <= steady["high"], (steady, expected)
    assert steady["static_z"] == STATIC_Z and 0.7 < steady["static_fraction"] < 0.75
    drifting, expected_drift = _run(drift=0.05, all_pixels=False, seed=3)
    assert drifting["low"] <= expected_drift <= drifting["high"]
    assert drifting["low"] > steady["high"], (drifting, steady)
    # Planted: differences over every pixel take in the moving rows' change.
    planted, _ = _run(drift=0.0, all_pixels=True, seed=2)
    assert planted["low"] > steady["high"], (planted, steady)


def test_no_static_region_or_a_nonfinite_seed_gives_no_mean():
    empty = np.zeros((SIZE, SIZE), bool)
    frame = np.ones((SIZE, SIZE, 3))
    assert frame_flicker(frame, frame, frame, empty, EPS) is None
    assert seed_flicker([None, None]) is None
    assert run_flicker([0.1, None], [0.0])["mean"] is None
    assert "NaN or infinite" in run_flicker([0.1, float("nan")], [1.0])["note"]
