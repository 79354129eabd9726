"""FLIP through NVIDIA's ``flip_evaluator`` package (never re-implemented here).

- HDR-FLIP evaluates the images over a range of exposures [start, stop] (in
  stops). FLIP derives that range from the *reference* (its max and median
  luminance); :func:`hdr_exposures` computes it once per reference so every
  run compared against that reference uses the same exposures, and
  :func:`flip_hdr` always passes them explicitly.
- LDR-FLIP compares display images: both images go through
  :func:`metrics.tonemap.to_display_srgb` (2^exposure, clamp to [0, 1], sRGB
  encoding) and FLIP treats the result as sRGB.

FLIP's other settings stay at the library defaults (67 pixels per degree,
ACES tone mapping inside HDR-FLIP).

Inputs: non-finite pixels are set to 0 and, for HDR-FLIP, negative values
(possible with the residual of two-level estimators) are clamped to 0, because
FLIP is defined for non-negative radiance. Callers count non-finite pixels
themselves (:func:`metrics.errors.image_metrics`).

Printing: on bad arguments ``flip_evaluator`` prints to stdout and exits the
process, from Python (``sys.exit``) or from C++ (``exit``, e.g. when the start
exposure exceeds the stop exposure, which FLIP's own heuristic produces for a
reference darker than ~1e-7). Redirecting stdout would be process-global and
unsafe next to other threads (Dask workers), so instead every argument is
validated here so that those paths are never reached; a normal evaluation
prints nothing.
"""

from __future__ import annotations

import math
import os
from typing import Any, NamedTuple

# FLIP's bundled OpenMP spins its waiting threads by default; with more threads than
# cores (the render processes and the service on 2 cores) a spinning thread holds the
# core the thread it waits for needs: an HDR-FLIP of a 4x4 image measured 0.3-0.4 s so,
# 0.3 ms passive, with the same values. Read when the library loads, so set before.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import flip_evaluator  # noqa: E402
import numpy as np  # noqa: E402

from metrics.checks import MetricError, as_rgb, check_same_shape, zero_nonfinite
from metrics.tonemap import to_display_srgb

#: Luminance weights of linear sRGB (Rec. 709), as FLIP uses for its exposure range.
LUMINANCE_WEIGHTS = np.array([0.2126, 0.7152, 0.0722])

# FLIP's exposure heuristic fails (and exits the process) when the reference's
# maximum luminance is below about 1e-7; dimmer references are rescaled first,
# with a wide margin.
_DIM_REFERENCE_LUMINANCE = 1e-3


class FlipExposures(NamedTuple):
    """HDR-FLIP's exposure range in stops (the image is multiplied by 2^c)."""

    start: float
    stop: float


def _hdr_input(img: np.ndarray) -> np.ndarray:
    """float32 contiguous copy with non-finite pixels zeroed and negatives clamped to 0."""
    arr = zero_nonfinite(img)
    np.maximum(arr, 0.0, out=arr)
    return np.ascontiguousarray(arr)


def _evaluate(ref: np.ndarray, test: np.ndarray, dynamic_range: str,
              parameters: dict[str, Any]) -> tuple[float, np.ndarray, dict[str, Any]]:
    """(mean, (H, W) float32 error map, parameters used) from ``flip_evaluator.evaluate``."""
    try:
        error_map, mean, used = flip_evaluator.evaluate(
            ref, test, dynamic_range, applyMagma=False, computeMeanError=True,
            parameters=dict(parameters))
    except (RuntimeError, ValueError, SystemExit) as err:
        # SystemExit: the wrapper's own argument checks; validated above, but a
        # metric must never end the process.
        raise MetricError(f"FLIP ({dynamic_range}) rejected its inputs: {err}") from None
    return float(mean), np.asarray(error_map, dtype=np.float32)[..., 0], used


def _check_exposures(exposures: tuple[float, float]) -> FlipExposures:
    try:
        start, stop = (float(value) for value in exposures)
    except (TypeError, ValueError):
        raise MetricError(f"FLIP exposures must be (start, stop), got {exposures!r}") from None
    if not (math.isfinite(start) and math.isfinite(stop) and start <= stop):
        raise MetricError(f"FLIP exposures must be finite with start <= stop, "
                          f"got ({start}, {stop})")
    return FlipExposures(start, stop)


def hdr_exposures(ref: np.ndarray) -> FlipExposures:
    """FLIP's (start, stop) exposure range for ``ref``, as FLIP itself would choose it.

    Computed by letting ``flip_evaluator`` evaluate the reference against
    itself and reading back the exposures it used. References dimmer than
    ``_DIM_REFERENCE_LUMINANCE`` are scaled to max luminance 1 first and the
    range shifted back by log2(scale) (scaling an image by s shifts every
    exposure by -log2 s), which avoids FLIP's failure on near-black images.
    An all-black reference gets (0, 0).
    """
    arr = _hdr_input(as_rgb(ref, "reference image"))
    max_luminance = float((arr.astype(np.float64) @ LUMINANCE_WEIGHTS).max())
    if max_luminance <= 0.0:
        return FlipExposures(0.0, 0.0)
    scale = 1.0 if max_luminance >= _DIM_REFERENCE_LUMINANCE else 1.0 / max_luminance
    scaled = np.ascontiguousarray(arr * np.float32(scale)) if scale != 1.0 else arr
    _, _, used = _evaluate(scaled, scaled, "HDR", {})
    shift = math.log2(scale)
    return FlipExposures(float(used["startExposure"]) + shift,
                         float(used["stopExposure"]) + shift)


def flip_hdr(ref: np.ndarray, test: np.ndarray,
             exposures: tuple[float, float]) -> tuple[float, np.ndarray]:
    """(mean HDR-FLIP, (H, W) float32 error map in [0, 1]) with fixed ``exposures``."""
    test, ref = check_same_shape(test, ref)
    ref, test = as_rgb(ref, "reference image"), as_rgb(test, "test image")
    start, stop = _check_exposures(exposures)
    return _evaluate(_hdr_input(ref), _hdr_input(test), "HDR",
                     {"startExposure": start, "stopExposure": stop})[:2]


def flip_ldr(ref: np.ndarray, test: np.ndarray,
             exposure: float = 0.0) -> tuple[float, np.ndarray]:
    """(mean LDR-FLIP, (H, W) float32 error map) after the clamp + sRGB tone mapper.

    Both images are scaled by 2^``exposure``, clamped to [0, 1] and
    sRGB-encoded (:func:`metrics.tonemap.to_display_srgb`) before FLIP.
    """
    test, ref = check_same_shape(test, ref)
    ref, test = as_rgb(ref, "reference image"), as_rgb(test, "test image")
    return _evaluate(to_display_srgb(ref, exposure), to_display_srgb(test, exposure),
                     "LDR", {})[:2]
