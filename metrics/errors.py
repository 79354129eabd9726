"""Error metrics of rendered images against a converged reference (DESIGN.md, "Metrics").

For a test image X and a reference R, per pixel p and channel c, averaged over
all pixels and channels:

- MSE  = mean (X - R)^2
- MRSE = mean (X - R)^2 / (R^2 + eps), eps = 0.01 unless configured
- over K independent renders: rBias^2 and rVar (:func:`bias_variance`)
- efficiency = 1 / (MRSE x seconds per frame)

Non-finite pixels (any channel NaN or +-Inf) are never averaged silently:
:func:`image_metrics` and :func:`bias_variance` count them, average over the
remaining pixels and report ``finite = False`` so the caller fails the run's
quality flag. The plain :func:`mse` / :func:`mrse` return NaN or Inf when
their input has such pixels.

All sums are accumulated in float64; inputs are usually float32.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from metrics.checks import (
    MetricError,
    as_image,
    check_eps,
    check_same_shape,
    finite_pixel_mask,
)
from metrics.statistics import mean_confidence_interval

__all__ = [
    "DEFAULT_EPS",
    "MetricError",
    "bias_variance",
    "count_nonfinite",
    "efficiency",
    "image_metrics",
    "mrse",
    "mse",
    "relative_squared_error_map",
]

DEFAULT_EPS = 0.01


def count_nonfinite(img: np.ndarray) -> int:
    """Number of pixels with at least one NaN or +-Inf channel."""
    return int(np.count_nonzero(~finite_pixel_mask(img)))


def _relative_weight(ref: np.ndarray, eps: float) -> np.ndarray:
    """1 / (R^2 + eps) in float64: the per-element weight that turns MSE into MRSE."""
    r = np.asarray(ref, dtype=np.float64)
    return 1.0 / (r * r + eps)


def _squared_error(test: np.ndarray, ref: np.ndarray) -> np.ndarray:
    diff = np.asarray(test, dtype=np.float64) - np.asarray(ref, dtype=np.float64)
    return diff * diff


def mse(test: np.ndarray, ref: np.ndarray) -> float:
    """Mean over all pixels and channels of (X - R)^2 (NaN/Inf if any pixel is non-finite)."""
    test, ref = check_same_shape(test, ref)
    with np.errstate(invalid="ignore", over="ignore"):
        return float(np.mean(_squared_error(test, ref)))


def mrse(test: np.ndarray, ref: np.ndarray, eps: float = DEFAULT_EPS) -> float:
    """Mean over all pixels and channels of (X - R)^2 / (R^2 + eps) (NaN/Inf if non-finite)."""
    test, ref = check_same_shape(test, ref)
    eps = check_eps(eps)
    with np.errstate(invalid="ignore", over="ignore"):
        return float(np.mean(_squared_error(test, ref) * _relative_weight(ref, eps)))


def relative_squared_error_map(test: np.ndarray, ref: np.ndarray,
                               eps: float = DEFAULT_EPS) -> np.ndarray:
    """(H, W) float32 map of (X - R)^2 / (R^2 + eps) averaged over channels.

    Its mean is :func:`mrse`. Non-finite pixels stay NaN/Inf in the map so that
    an error-map image shows them (previews paint them at the top of the scale).
    """
    test, ref = check_same_shape(test, ref)
    eps = check_eps(eps)
    with np.errstate(invalid="ignore", over="ignore"):
        per_channel = _squared_error(test, ref) * _relative_weight(ref, eps)
    return per_channel.mean(axis=-1).astype(np.float32)


def _finite_pixel_errors(test: np.ndarray, ref: np.ndarray, valid: np.ndarray,
                         eps: float) -> tuple[float | None, float | None]:
    """(MSE, MRSE) over the pixels where ``valid`` is True; None when there are none."""
    if not valid.any():
        return None, None
    x, r = test[valid], ref[valid]
    squared = _squared_error(x, r)
    return float(squared.mean()), float((squared * _relative_weight(r, eps)).mean())


def image_metrics(
    test: np.ndarray,
    ref: np.ndarray,
    eps: float = DEFAULT_EPS,
    flip_exposures: tuple[float, float] | None = None,
    with_flip: bool = True,
    return_maps: bool = False,
) -> dict[str, Any]:
    """All single-image metrics of ``test`` against ``ref``, as JSON-ready values.

    Returns a dict with

    - ``mse``, ``mrse``: averages over the pixels finite in both images (None if
      no pixel is);
    - ``flip_hdr``, ``flip_ldr``: FLIP means (None when ``with_flip`` is False);
      HDR-FLIP uses ``flip_exposures`` (start, stop) — pass the ones stored with
      the reference so every run against it is comparable; when None they are
      computed from ``ref`` (:func:`metrics.flip.hdr_exposures`). FLIP needs
      whole images, so non-finite pixels are zeroed for it;
    - ``flip_exposures``: [start, stop] used (None without FLIP);
    - ``nonfinite_pixels`` (in ``test``), ``ref_nonfinite_pixels``;
    - ``finite``: False when either count is non-zero (the run's quality flag);
    - ``error_maps`` (only when ``return_maps``): (H, W) float32 arrays
      ``relative_squared_error``, and ``flip_hdr`` / ``flip_ldr`` with FLIP.

    Raises MetricError when the shapes differ.
    """
    test, ref = check_same_shape(test, ref)
    eps = check_eps(eps)
    test_ok, ref_ok = finite_pixel_mask(test), finite_pixel_mask(ref)
    mse_value, mrse_value = _finite_pixel_errors(test, ref, test_ok & ref_ok, eps)
    nonfinite, ref_nonfinite = int((~test_ok).sum()), int((~ref_ok).sum())
    result: dict[str, Any] = {
        "mse": mse_value,
        "mrse": mrse_value,
        "flip_hdr": None,
        "flip_ldr": None,
        "flip_exposures": None,
        "nonfinite_pixels": nonfinite,
        "ref_nonfinite_pixels": ref_nonfinite,
        "finite": nonfinite == 0 and ref_nonfinite == 0,
    }
    maps: dict[str, np.ndarray] = {}
    if with_flip:
        # Imported here so that MSE/MRSE users do not load the FLIP extension.
        from metrics.flip import flip_hdr, flip_ldr, hdr_exposures

        exposures = hdr_exposures(ref) if flip_exposures is None else flip_exposures
        result["flip_hdr"], maps["flip_hdr"] = flip_hdr(ref, test, exposures)
        result["flip_ldr"], maps["flip_ldr"] = flip_ldr(ref, test)
        result["flip_exposures"] = [float(exposures[0]), float(exposures[1])]
    if return_maps:
        maps["relative_squared_error"] = relative_squared_error_map(test, ref, eps)
        result["error_maps"] = maps
    return result


def _as_render_list(images: np.ndarray | Sequence[np.ndarray]) -> list[np.ndarray]:
    """K renders as a list of (H, W, C) arrays, from a (K, H, W, C) stack or a sequence."""
    if isinstance(images, np.ndarray):
        if images.ndim != 4:
            raise MetricError(f"renders must be stacked as (K, H, W, C), got shape {images.shape}")
        renders = list(images)
    else:
        renders = [as_image(img, "render") for img in images]
    if len(renders) < 2:
        raise MetricError(f"rBias^2/rVar need K >= 2 independent renders, got K = {len(renders)}")
    return renders


def bias_variance(images: np.ndarray | Sequence[np.ndarray], ref: np.ndarray,
                  eps: float = DEFAULT_EPS) -> dict[str, Any]:
    """Relative bias^2 and variance from K >= 2 independent renders X_k (DESIGN.md).

    With the per-pixel mean M = (1/K) sum_k X_k, the unbiased sample variance
    S^2 = sum_k (X_k - M)^2 / (K - 1) and the weight w = 1 / (R^2 + eps), all
    averaged over pixels and channels:

    - ``rbias2_raw``  = mean (M - R)^2 w
    - ``noise_floor`` = mean S^2 / K w   (the part of the raw term due to noise in M)
    - ``rbias2``      = rbias2_raw - noise_floor (an unbiased estimate, so it
      can be negative for an unbiased method; reported as computed)
    - ``rvar``        = mean S^2 w
    - ``mrse_per_seed`` = [MRSE(X_k)], ``mrse_mean`` their mean and
      ``mrse_ci95`` = (lo, hi), the Student-t 95 % interval over the K values.

    Why E[MRSE] = rBias^2 + rVar: for each pixel,
    (1/K) sum_k (X_k - R)^2 = (M - R)^2 + (1/K) sum_k (X_k - M)^2
                            = (M - R)^2 + (K-1)/K S^2,
    so, exactly (up to rounding), mean_k MRSE_k = rbias2_raw + (K-1)/K rvar
    = rbias2 + rvar. In expectation E[S^2] = Var X and E[(M - R)^2] =
    bias^2 + Var X / K, hence E[rbias2] and E[rvar] are the true relative
    bias^2 and variance of one render, and they add up to its expected MRSE.

    Pixels non-finite in the reference or in *any* render are excluded from all
    terms (one pixel set keeps the identity exact); they are counted in
    ``nonfinite_pixels`` (union over renders), ``nonfinite_pixels_per_seed`` and
    ``ref_nonfinite_pixels``, and make ``finite`` False. MRSE per seed here is
    therefore over that common pixel set. Also returned: ``k``. Averages are
    None when no pixel is finite everywhere.

    ``images`` is a (K, H, W, C) array or a sequence of (H, W, C) arrays; the
    renders are visited one at a time (memory stays O(H W) beyond the input).
    """
    renders = _as_render_list(images)
    ref = as_image(ref, "reference image")
    eps = check_eps(eps)
    for x in renders:
        check_same_shape(x, ref)
    k = len(renders)

    ref_ok = finite_pixel_mask(ref)
    render_ok = [finite_pixel_mask(x) for x in renders]
    all_ok = np.logical_and.reduce(render_ok)
    valid = ref_ok & all_ok
    counts: dict[str, Any] = {
        "k": k,
        "nonfinite_pixels": int((~all_ok).sum()),
        "nonfinite_pixels_per_seed": [int((~ok).sum()) for ok in render_ok],
        "ref_nonfinite_pixels": int((~ref_ok).sum()),
    }
    counts["finite"] = counts["nonfinite_pixels"] == 0 and counts["ref_nonfinite_pixels"] == 0
    if not valid.any():
        return {**counts, "rbias2": None, "rbias2_raw": None, "noise_floor": None,
                "rvar": None, "mrse_mean": None, "mrse_ci95": None, "mrse_per_seed": None}

    r = np.asarray(ref[valid], dtype=np.float64)
    w = _relative_weight(r, eps)
    # Two passes over the renders (mean, then deviations) instead of one stacked
    # float64 array: exact sample variance without K copies of the image.
    m = np.zeros_like(r)
    for x in renders:
        m += x[valid]
    m /= k
    sum_sq_dev = np.zeros_like(r)
    mrse_per_seed = []
    for x in renders:
        xk = np.asarray(x[valid], dtype=np.float64)
        sum_sq_dev += (xk - m) ** 2
        mrse_per_seed.append(float(np.mean((xk - r) ** 2 * w)))
    s2 = sum_sq_dev / (k - 1)

    rbias2_raw = float(np.mean((m - r) ** 2 * w))
    rvar = float(np.mean(s2 * w))
    noise_floor = rvar / k
    mrse_mean, lo, hi = mean_confidence_interval(mrse_per_seed, 0.95)
    return {
        **counts,
        "rbias2": rbias2_raw - noise_floor,
        "rbias2_raw": rbias2_raw,
        "noise_floor": noise_floor,
        "rvar": rvar,
        "mrse_mean": mrse_mean,
        "mrse_ci95": (lo, hi),
        "mrse_per_seed": mrse_per_seed,
    }


def efficiency(mrse: float, seconds_per_frame: float) -> float:
    """1 / (MRSE x time), time being steady-state seconds per frame (higher is better)."""
    for name, value in (("MRSE", mrse), ("seconds per frame", seconds_per_frame)):
        if value is None or not (math.isfinite(value) and value > 0):
            raise MetricError(f"efficiency needs a finite {name} > 0, got {value!r}")
    return 1.0 / (float(mrse) * float(seconds_per_frame))
