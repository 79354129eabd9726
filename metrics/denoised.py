"""Denoised error: MRSE and HDR-FLIP of a seed's frames after Intel Open Image Denoise.

The variance-trading paper judges termination policies by what a denoiser makes of
their output (Sec. 7, Fig. 8, 10 and 11: SVGF, "its result after four still frames").
SVGF is a temporal, real-time filter: it needs motion vectors, the previous frame's
history and the renderer's G-buffer in its own pipeline. Intel Open Image Denoise
(OIDN, the ``pyoidn`` package, its CPU device) is a still-image denoiser that a
benchmark can call on any stored image, so it stands in for SVGF here
(docs/metrics.md, "Denoised error"). Both see the same auxiliary features: albedo and
normal at the first hit.

Per seed, from its last :data:`ACCUMULATED_FRAMES` frames (all of its frames when it
has fewer; ``denoised_frames`` says how many):

- ``denoised_mrse_frame``, ``denoised_flip_frame``: the mean over those frames of the
  MRSE and HDR-FLIP of each frame denoised alone (the paper's 1-spp row);
- ``denoised_mrse_accum``, ``denoised_flip_accum``: MRSE and HDR-FLIP of their mean,
  denoised ("after four still frames").

MRSE is :func:`metrics.errors.image_metrics`'s (over the pixels where the reference is
finite), HDR-FLIP :func:`metrics.flip.flip_hdr` at the reference's exposures, as for
the raw metrics. OIDN reads radiance as non-negative and silently zeroes NaN and
infinite values; so a frame with a non-finite pixel is not denoised (its seed's values
are None and ``denoised_note`` says why), and negative values (a two-level estimator's
residual) are clamped to 0 before denoising and counted (``denoised_negative_values``).
This module is numpy-only: the features come from the caller
(renderers.denoise_features renders them).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from metrics.checks import MetricError, as_rgb, check_same_shape, finite_pixel_mask
from metrics.errors import image_metrics

#: Frames accumulated before denoising: the paper's "four still frames".
ACCUMULATED_FRAMES = 4
#: OIDN's RT filter settings (its documentation's names): radiance is HDR, the features
#: are noise-free (rendered at many spp, renderers.denoise_features), highest quality.
OIDN_SETTINGS = {"filter": "RT", "hdr": True, "cleanAux": True, "quality": "high"}
#: Key of a run's metrics that holds the denoiser's provenance (only where it denoised).
DENOISER_KEY = "denoiser"
#: Stored keys of a seed's denoised values (per seed, and ``<key>_mean`` over seeds).
DENOISED_KEYS = ("denoised_mrse_frame", "denoised_flip_frame", "denoised_mrse_accum",
                 "denoised_flip_accum")


class Features(NamedTuple):
    """OIDN's auxiliary images at the first hit: (H, W, 3) float32 each."""

    albedo: np.ndarray   # in [0, 1]
    normal: np.ndarray   # world space, in [-1, 1]; 0 where the camera ray leaves the scene


#: (colour, features) -> the denoised colour, of the colour's shape.
Denoiser = Callable[[np.ndarray, Features], np.ndarray]


def oidn_denoise(color: np.ndarray, features: Features) -> np.ndarray:
    """``color`` (non-negative linear radiance) denoised by OIDN's RT filter with the
    albedo and normal features (:data:`OIDN_SETTINGS`); MetricError naming OIDN's own
    message where it fails (a device it cannot create, an unsupported CPU)."""
    try:
        import pyoidn  # the native library loads only where a run denoises

        return pyoidn.denoise(color, features.albedo, features.normal, hdr=True,
                              clean_aux=True, quality="high")
    except (ImportError, OSError, RuntimeError) as err:
        raise MetricError(f"Intel Open Image Denoise failed: {err}") from None


def denoiser_provenance() -> dict[str, Any]:
    """What denoised a run's frames: OIDN's version and the filter settings."""
    from pyoidn.version import oidn_version

    return {"library": "Intel Open Image Denoise", "version": oidn_version,
            **OIDN_SETTINGS, "accumulated_frames": ACCUMULATED_FRAMES}


def check_features(features: Features, shape: tuple[int, ...]) -> Features:
    """``features`` as contiguous float32 images of ``shape``, finite; MetricError if not."""
    checked = []
    for name, image in zip(Features._fields, features, strict=True):
        image = as_rgb(image, f"{name} feature image")
        if image.shape != shape:
            raise MetricError(f"{name} feature image shape {image.shape} does not match the "
                              f"frames' {shape}")
        if not finite_pixel_mask(image).all():
            raise MetricError(f"the {name} feature image has non-finite pixels")
        checked.append(np.ascontiguousarray(image, dtype=np.float32))
    return Features(*checked)


def _denoiser_input(image: np.ndarray) -> tuple[np.ndarray, int]:
    """(float32 contiguous copy with negatives clamped to 0, how many values were < 0)."""
    arr = np.ascontiguousarray(image, dtype=np.float32)
    negative = int(np.count_nonzero(arr < 0))
    return np.maximum(arr, 0.0), negative


def _errors(denoised: np.ndarray, reference: np.ndarray, eps: float,
            flip_exposures: tuple[float, float]) -> tuple[float | None, float]:
    """(MRSE, HDR-FLIP) of a denoised image; MetricError when the denoiser returned
    non-finite pixels (they would be left out of MRSE and zeroed for FLIP)."""
    denoised, reference = check_same_shape(denoised, reference)
    from metrics.flip import flip_hdr  # as metrics.errors: the registry loads no FLIP

    bad = int(np.count_nonzero(~finite_pixel_mask(denoised)))
    if bad:
        raise MetricError(f"the denoiser returned {bad} non-finite pixels")
    mrse = image_metrics(denoised, reference, eps, with_flip=False)["mrse"]
    return mrse, flip_hdr(reference, denoised, flip_exposures)[0]


def denoised_metrics(frames: Sequence[np.ndarray], reference: np.ndarray, eps: float,
                     flip_exposures: tuple[float, float], features: Features,
                     denoise: Denoiser = oidn_denoise) -> dict[str, Any]:
    """A seed's denoised values (module docstring) from its last frames ``frames``
    (oldest first; the last :data:`ACCUMULATED_FRAMES` are used).

    Every value is None, and ``denoised_note`` says why, when a frame has a non-finite
    pixel or the denoiser returns one; raises MetricError for malformed input.
    """
    if not frames:
        raise MetricError("denoised metrics need at least one frame")
    used = [as_rgb(frame, "frame") for frame in frames[-ACCUMULATED_FRAMES:]]
    features = check_features(features, used[0].shape)
    result: dict[str, Any] = {**dict.fromkeys(DENOISED_KEYS), "denoised_frames": len(used),
                              "denoised_negative_values": 0, "denoised_note": None}
    nonfinite = sum(int(np.count_nonzero(~finite_pixel_mask(f))) for f in used)
    if nonfinite:
        result["denoised_note"] = (f"not denoised: the last {len(used)} frames have "
                                   f"{nonfinite} non-finite pixels")
        return result
    # The accumulation is the plain mean of the frames, in float64 (as the raw running mean).
    accumulated = np.mean(np.stack(used).astype(np.float64), axis=0)
    try:
        per_frame = []
        for image in [*used, accumulated]:
            color, negative = _denoiser_input(image)
            result["denoised_negative_values"] += negative
            per_frame.append(_errors(denoise(color, features), reference, eps, flip_exposures))
    except MetricError as err:
        return {**result, "denoised_note": f"not denoised: {err}"}
    frame_errors, (result["denoised_mrse_accum"], result["denoised_flip_accum"]) = \
        per_frame[:-1], per_frame[-1]
    mrse_values = [mrse for mrse, _ in frame_errors]
    result["denoised_mrse_frame"] = (None if None in mrse_values
                                     else float(np.mean(mrse_values)))
    result["denoised_flip_frame"] = float(np.mean([flip for _, flip in frame_errors]))
    return result
