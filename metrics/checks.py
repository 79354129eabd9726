"""Shape and finiteness checks shared by every metric, and the error they raise.

Images in ``metrics`` are numpy arrays of shape (H, W, C) in linear RGB
(C = 3 for colour images). A *pixel* is non-finite when any of its channels is
NaN or +-Inf; metrics count such pixels instead of averaging them (docs/metrics.md).
"""

from __future__ import annotations

import math

import numpy as np


class MetricError(ValueError):
    """A metric cannot be computed from these inputs (the message says why)."""


def as_image(img: np.ndarray, name: str = "image") -> np.ndarray:
    """``img`` as an (H, W, C) array, or MetricError naming ``name``."""
    arr = np.asarray(img)
    if arr.ndim != 3 or arr.shape[0] == 0 or arr.shape[1] == 0 or arr.shape[2] == 0:
        raise MetricError(f"{name} must be an (H, W, C) image with H, W, C >= 1, "
                          f"got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.floating) and not np.issubdtype(arr.dtype, np.integer):
        raise MetricError(f"{name} must hold real numbers, got dtype {arr.dtype}")
    return arr


def as_rgb(img: np.ndarray, name: str = "image") -> np.ndarray:
    """``img`` as an (H, W, 3) array, or MetricError naming ``name``."""
    arr = as_image(img, name)
    if arr.shape[2] != 3:
        raise MetricError(f"{name} must have 3 (RGB) channels, got shape {arr.shape}")
    return arr


def check_same_shape(test: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both images as arrays; MetricError naming both shapes when they differ."""
    test_arr = as_image(test, "test image")
    ref_arr = as_image(ref, "reference image")
    if test_arr.shape != ref_arr.shape:
        raise MetricError(f"test image shape {test_arr.shape} does not match "
                          f"reference image shape {ref_arr.shape}")
    return test_arr, ref_arr


def check_eps(eps: float) -> float:
    """``eps`` as a float; it must be finite and > 0 or R = 0 pixels divide by zero."""
    value = float(eps)
    if not (math.isfinite(value) and value > 0.0):
        raise MetricError(f"eps must be a finite number > 0, got {eps!r}")
    return value


def finite_pixel_mask(img: np.ndarray) -> np.ndarray:
    """(H, W) bool: True where every channel of the pixel is finite."""
    return np.isfinite(as_image(img)).all(axis=-1)


def zero_nonfinite(img: np.ndarray) -> np.ndarray:
    """float32 copy of ``img`` with every non-finite pixel set to 0 in all channels.

    Used where a whole image must be passed on (FLIP, previews): those consumers
    cannot skip pixels, and the callers count the zeroed pixels separately.
    """
    arr = as_image(img).astype(np.float32, copy=True)
    arr[~finite_pixel_mask(arr)] = 0.0
    return arr
