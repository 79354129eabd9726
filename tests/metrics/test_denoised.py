"""The denoised errors (metrics.denoised): OIDN lowers the error of noisy path-traced
frames of a smooth scene, and the inputs OIDN would silently alter are refused or counted."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from metrics.denoised import Features, denoised_metrics, oidn_denoise
from metrics.errors import mrse
from metrics.flip import flip_hdr, hdr_exposures

EPS = 0.01
SEEDS = 4
FRAMES = 4


@pytest.fixture(scope="module")
def empty_box(mi):
    """An empty Cornell box (diffuse walls and the ceiling light, no boxes) at 32x32, and
    its scene description."""
    scene_dict = mi.cornell_box()
    del scene_dict["small-box"], scene_dict["large-box"]
    scene_dict["sensor"]["film"].update(width=32, height=32)
    return mi.load_dict(scene_dict), scene_dict


@pytest.fixture(scope="module")
def smooth_renders(mi, empty_box):
    """The empty box's SEEDS x FRAMES independent 1-spp path-traced frames, a 1024-spp
    reference and the denoiser's features (renderers.denoise_features)."""
    from renderers.denoise_features import render_features

    scene = empty_box[0]
    path = mi.load_dict({"type": "path", "max_depth": 6})
    frames = [[np.asarray(mi.render(scene, integrator=path, spp=1, seed=1 + FRAMES * k + f))
               for f in range(FRAMES)] for k in range(SEEDS)]
    reference = np.asarray(mi.render(scene, integrator=path, spp=1024, seed=10_000))
    return frames, reference, render_features(scene)


def _identity(color: np.ndarray, _features: Features) -> np.ndarray:
    """A planted "denoiser" that changes nothing."""
    return color


def _check_denoising_lowers_errors(smooth_renders, denoise) -> None:
    """Per seed the log ratio of denoised to raw error (MRSE and HDR-FLIP, of a frame and
    of the four frames' mean); the upper end of the one-sided 95 % Student-t bound on the
    mean log ratio over the SEEDS seeds must be below 0 for all four."""
    frames, reference, features = smooth_renders
    exposures = hdr_exposures(reference)
    ratios: dict[str, list[float]] = {}
    for seed_frames in frames:
        values = denoised_metrics(seed_frames, reference, EPS, exposures, features, denoise)
        accumulated = np.mean(seed_frames, axis=0)
        raw = {"mrse_frame": np.mean([mrse(f, reference, EPS) for f in seed_frames]),
               "flip_frame": np.mean([flip_hdr(reference, f, exposures)[0]
                                      for f in seed_frames]),
               "mrse_accum": mrse(accumulated, reference, EPS),
               "flip_accum": flip_hdr(reference, accumulated, exposures)[0]}
        for name, value in raw.items():
            ratios.setdefault(name, []).append(np.log(values[f"denoised_{name}"] / value))
    t = stats.t.ppf(0.95, SEEDS - 1)
    for name, logs in ratios.items():
        upper = np.mean(logs) + t * np.std(logs, ddof=1) / np.sqrt(SEEDS)
        assert upper < 0, f"{name}: denoised / raw error {np.exp(logs)}"


def test_oidn_lowers_mrse_and_flip_of_noisy_frames_of_a_smooth_scene(smooth_renders):
    # Measured here (per seed, denoised / raw): MRSE 0.56-0.70 of a frame and 0.61-0.76 of
    # the four frames' mean, HDR-FLIP 0.88-0.91 and 0.88-0.96.
    _check_denoising_lowers_errors(smooth_renders, oidn_denoise)


def test_a_planted_identity_denoiser_fails_the_check(smooth_renders):
    with pytest.raises(AssertionError):
        _check_denoising_lowers_errors(smooth_renders, _identity)


def test_the_features_are_albedo_and_normal_at_the_first_hit(empty_box):
    """The image's centre sees the back wall: the white diffuse reflectance and the
    wall's normal towards the camera (+z); the same again (a fixed seed: the same
    samples, summed into the film's pixels in the threads' order)."""
    from renderers.denoise_features import render_features

    scene, scene_dict = empty_box
    features = render_features(scene, spp=16)
    white = scene_dict["white"]["reflectance"]["value"]
    np.testing.assert_allclose(features.albedo[15:17, 15:17], np.broadcast_to(white, (2, 2, 3)),
                               rtol=1e-5)
    np.testing.assert_allclose(features.normal[15:17, 15:17],
                               np.broadcast_to([0.0, 0.0, 1.0], (2, 2, 3)), atol=1e-5)
    assert features.albedo.max() <= 1 and np.abs(features.normal).max() <= 1
    again = render_features(scene, spp=16)
    for image, repeated in zip(features, again, strict=True):
        np.testing.assert_allclose(repeated, image, rtol=1e-5, atol=1e-6)


# ---- Inputs (a box blur stands in for OIDN: these tests are about the bookkeeping) ----

SHAPE = (6, 5, 3)
FEATURES = Features(np.full(SHAPE, 0.5, np.float32), np.zeros(SHAPE, np.float32))
REFERENCE = np.full(SHAPE, 1.0, np.float32)


def _calls(log: list[np.ndarray]):
    def denoise(color: np.ndarray, _features: Features) -> np.ndarray:
        log.append(color.copy())
        return np.full_like(color, color.mean())

    return denoise


def test_only_the_last_four_frames_are_denoised_each_and_as_their_mean():
    rng = np.random.default_rng(1)
    frames = [np.full(SHAPE, np.nan, np.float32)] * 2 + \
        [rng.uniform(0.5, 1.5, SHAPE).astype(np.float32) for _ in range(4)]
    log: list[np.ndarray] = []
    values = denoised_metrics(frames, REFERENCE, EPS, (0.0, 0.0), FEATURES, _calls(log))
    # The two NaN frames before the last four are not used; four frames and their mean are.
    assert values["denoised_frames"] == 4 and values["denoised_note"] is None
    assert len(log) == 5
    np.testing.assert_allclose(log[-1], np.mean(frames[2:], axis=0), rtol=1e-6)
    assert values["denoised_mrse_accum"] == pytest.approx(
        mrse(np.full(SHAPE, log[-1].mean()), REFERENCE, EPS))
    short = denoised_metrics(frames[-2:], REFERENCE, EPS, (0.0, 0.0), FEATURES, _calls([]))
    assert short["denoised_frames"] == 2


def test_a_nonfinite_frame_is_not_denoised_and_says_why():
    frames = [np.ones(SHAPE, np.float32) for _ in range(4)]
    frames[3] = frames[3].copy()
    frames[3][1, 1, 0] = np.inf
    log: list[np.ndarray] = []
    values = denoised_metrics(frames, REFERENCE, EPS, (0.0, 0.0), FEATURES, _calls(log))
    assert not log and "1 non-finite pixels" in values["denoised_note"]
    assert values["denoised_mrse_frame"] is None and values["denoised_flip_accum"] is None


def test_a_nonfinite_denoised_image_is_not_scored():
    values = denoised_metrics([np.ones(SHAPE, np.float32)], REFERENCE, EPS, (0.0, 0.0),
                              FEATURES, lambda color, _f: np.full_like(color, np.nan))
    assert "non-finite" in values["denoised_note"] and values["denoised_mrse_frame"] is None


def test_negative_values_are_clamped_to_zero_before_denoising_and_counted():
    frame = np.ones(SHAPE, np.float32)
    frame[0, 0] = -2.0          # three channel values
    log: list[np.ndarray] = []
    values = denoised_metrics([frame], REFERENCE, EPS, (0.0, 0.0), FEATURES, _calls(log))
    assert all(image.min() >= 0 for image in log)
    # The frame alone and the mean of the one frame: 3 values each.
    assert values["denoised_negative_values"] == 6


def test_a_failing_denoiser_leaves_the_seed_unscored_with_its_message(monkeypatch):
    import pyoidn

    def fail(*_args, **_kwargs):
        raise RuntimeError("OIDN device creation failed (error 1): no CPU support")

    monkeypatch.setattr(pyoidn, "denoise", fail)
    values = denoised_metrics([np.ones(SHAPE, np.float32)], REFERENCE, EPS, (0.0, 0.0),
                              FEATURES)
    assert values["denoised_mrse_accum"] is None
    assert "Intel Open Image Denoise failed: OIDN device creation" in values["denoised_note"]
