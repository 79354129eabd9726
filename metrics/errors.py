"""Error metrics of rendered images against a converged reference (docs/metrics.md).

For a test image X and a reference R, per pixel p and channel c, averaged over
all pixels and channels:

- MSE  = mean (X - R)^2
- MRSE = mean (X - R)^2 / (R^2 + eps), eps = 0.01 unless configured
- over K independent renders: rBias^2 and rVar (:func:`bias_variance`), and
  per cache from each render's frames (:func:`per_cache_bias_variance`)
- efficiency = 1 / (MRSE x seconds per frame)
- PSNR of the tone-mapped images (:func:`psnr_tonemapped`): both through the
  project's display transform "clamp + sRGB" (:func:`metrics.tonemap.to_display_srgb`),
  then 10 log10(1 / MSE) on [0, 1] values, capped at PSNR_MAX_DB

The reference is itself a Monte Carlo mean: with its per-pixel variance image
Var[R] every squared error against it contains the *reference floor*
mean Var[R] / (R^2 + eps). Given ``ref_variance`` the functions report that
floor, subtract it from rBias^2 and MRSE, and warn when it is more than 10 %
of a reported value.

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

from metrics.bias_intervals import pooled_intervals, seed_gram
from metrics.checks import (
    MetricError,
    as_image,
    check_eps,
    check_same_shape,
    finite_pixel_mask,
)
from metrics.statistics import MeanEstimate, interval_or_reason
from metrics.tonemap import to_display_srgb

__all__ = [
    "DEFAULT_EPS",
    "MetricError",
    "bias_variance",
    "count_nonfinite",
    "efficiency",
    "image_metrics",
    "mrse",
    "mse",
    "per_cache_bias_variance",
    "psnr_tonemapped",
    "relative_squared_error_map",
]

DEFAULT_EPS = 0.01
#: PSNR of identical (display) images, and the cap of every PSNR: a number that can be
#: stored as JSON, sorted and plotted, where 10 log10(1 / 0) would be +inf.
PSNR_MAX_DB = 100.0
#: Warn when the reference floor is more than this fraction of a reported value.
REF_FLOOR_WARN_RATIO = 0.1


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


def _finite_pixel_errors(test: np.ndarray, ref: np.ndarray, ref_variance: np.ndarray | None,
                         valid: np.ndarray, eps: float) -> tuple[float, float, float | None]:
    """(MSE, MRSE, reference floor) over the pixels where ``valid`` is True (some must be)."""
    x, r = test[valid], ref[valid]
    squared = _squared_error(x, r)
    w = _relative_weight(r, eps)
    return (float(squared.mean()), float((squared * w).mean()),
            _reference_floor(ref_variance, valid, w))


def _reference_ok(ref: np.ndarray, ref_variance: np.ndarray | None) -> np.ndarray:
    """(H, W) bool: pixels where the reference (and its variance image, if given) are finite.

    Raises MetricError when the variance image has another shape or a negative value.
    """
    ok = finite_pixel_mask(ref)
    if ref_variance is None:
        return ok
    variance = as_image(ref_variance, "reference variance image")
    if variance.shape != ref.shape:
        raise MetricError(f"reference variance image shape {variance.shape} does not match "
                          f"reference image shape {ref.shape}")
    if np.any(variance < 0):
        raise MetricError("the reference variance image has negative values")
    return ok & finite_pixel_mask(variance)


def _reference_floor(ref_variance: np.ndarray | None, valid: np.ndarray,
                     w: np.ndarray) -> float | None:
    """mean Var[R] / (R^2 + eps) over the ``valid`` pixels (``w`` holds their weights)."""
    if ref_variance is None:
        return None
    return float(np.mean(np.asarray(ref_variance[valid], dtype=np.float64) * w))


def _floor_report(ref_floor: float | None, values: dict[str, float | None]) -> dict[str, Any]:
    """``ref_floor_ratio_<name>`` = ref_floor / |value| per reported value, and ``warnings``.

    A ratio is None without a floor or when the value is None or 0; a warning is
    given whenever the floor exceeds REF_FLOOR_WARN_RATIO x |value|.
    """
    report: dict[str, Any] = {}
    warnings: list[str] = []
    for name, value in values.items():
        ratio = None
        if ref_floor is not None and value:
            ratio = ref_floor / abs(value)
        report[f"ref_floor_ratio_{name}"] = ratio
        if ref_floor is not None and value is not None and ref_floor > REF_FLOOR_WARN_RATIO * abs(value):
            sign = ("; the estimate is below the noise floors, i.e. indistinguishable "
                    "from 0" if value < 0 else "")
            warnings.append(
                f"reference floor {ref_floor:.3g} exceeds {REF_FLOOR_WARN_RATIO:.0%} of the "
                f"magnitude of {name} ({abs(value):.3g}, floor subtracted{sign}): the value "
                "rests on the reference's variance image")
    report["warnings"] = warnings
    return report


def image_metrics(
    test: np.ndarray,
    ref: np.ndarray,
    eps: float = DEFAULT_EPS,
    flip_exposures: tuple[float, float] | None = None,
    with_flip: bool = True,
    return_maps: bool = False,
    ref_variance: np.ndarray | None = None,
) -> dict[str, Any]:
    """All single-image metrics of ``test`` against ``ref``, as JSON-ready values.

    Returns a dict with

    - ``mse``, ``mrse``: averages over the pixels finite in both images (None if
      no pixel is);
    - with ``ref_variance`` (the reference's per-pixel variance of its mean):
      ``ref_floor`` = mean Var[R] / (R^2 + eps) over the same pixels,
      ``mrse_corrected`` = mrse - ref_floor (an unbiased estimate of the MRSE
      against the true image), ``ref_floor_ratio_mrse`` = ref_floor / mrse and
      ``warnings`` (a list of strings; see :func:`_floor_report`); without it
      the three values are None and ``warnings`` is empty;
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

    Pixels where the variance image is non-finite count as non-finite
    reference pixels. Raises MetricError when the shapes differ.
    """
    test, ref = check_same_shape(test, ref)
    eps = check_eps(eps)
    test_ok, ref_ok = finite_pixel_mask(test), _reference_ok(ref, ref_variance)
    valid = test_ok & ref_ok
    mse_value = mrse_value = ref_floor = mrse_corrected = None
    if valid.any():
        mse_value, mrse_value, ref_floor = _finite_pixel_errors(test, ref, ref_variance, valid,
                                                                eps)
        mrse_corrected = None if ref_floor is None else mrse_value - ref_floor
    nonfinite, ref_nonfinite = int((~test_ok).sum()), int((~ref_ok).sum())
    result: dict[str, Any] = {
        "mse": mse_value,
        "mrse": mrse_value,
        "ref_floor": ref_floor,
        "mrse_corrected": mrse_corrected,
        **_floor_report(ref_floor, {"mrse": mrse_corrected}),
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
                  eps: float = DEFAULT_EPS,
                  ref_variance: np.ndarray | None = None) -> dict[str, Any]:
    """Relative bias^2 and variance from K >= 2 independent renders X_k (docs/metrics.md).

    With the per-pixel mean M = (1/K) sum_k X_k, the unbiased sample variance
    S^2 = sum_k (X_k - M)^2 / (K - 1) and the weight w = 1 / (R^2 + eps), all
    averaged over pixels and channels:

    - ``rbias2_raw``  = mean (M - R)^2 w
    - ``noise_floor`` = mean S^2 / K w   (the part of the raw term due to noise in M)
    - ``ref_floor``   = mean Var[R] w    (the part due to noise in R; None
      without ``ref_variance``, and then taken as 0 below)
    - ``rbias2``      = rbias2_raw - noise_floor - ref_floor (an unbiased
      estimate, so it can be negative for an unbiased method; reported as computed)
    - ``rvar``        = mean S^2 w
    - ``mrse_per_seed`` = [MRSE(X_k)], ``mrse_mean`` their mean and
      ``mrse_ci95`` = (lo, hi), its 95 % interval on the log scale, never below zero
      (metrics.statistics.positive_mean_interval; None with K < 3), and
      ``mrse_ci_note`` how it was made or why there is none;
      ``mrse_corrected`` = mrse_mean - ref_floor (None without a floor)
    - ``rbias2_pooled`` = ``rbias2``, which a method training a cache per seed replaces
      by the mean over its caches (metrics.bias_intervals.per_cache_headline);
      ``rbias2_seed_values`` and ``rvar_seed_values`` (the delete-one-seed jackknife
      values, whose means are rbias2 and rvar), ``rbias2_ci95`` / ``rvar_ci95`` (95 %
      intervals; None with K < 3) with ``rbias2_ci_note`` / ``rvar_ci_note``, and
      ``rbias2_basis`` = "pooled" (metrics.bias_intervals.pooled_intervals)
    - ``ref_floor_ratio_rbias2`` / ``ref_floor_ratio_mrse`` = ref_floor / |rbias2|
      and / |mrse_corrected|, and ``warnings`` (floor above 10 % of either).

    Why E[MRSE] = rBias^2 + rVar: for each pixel,
    (1/K) sum_k (X_k - R)^2 = (M - R)^2 + (1/K) sum_k (X_k - M)^2
                            = (M - R)^2 + (K-1)/K S^2,
    so, exactly (up to rounding), mean_k MRSE_k = rbias2_raw + (K-1)/K rvar
    = rbias2 + rvar + ref_floor. In expectation over renders and reference,
    E[(M - R)^2] = bias^2 + Var X / K + Var R and E[S^2] = Var X, hence
    E[rbias2] and E[rvar] are the true relative bias^2 and variance of one
    render against the true image (up to the noise of R in the weight w).

    Pixels non-finite in the reference (or its variance image) or in *any*
    render are excluded from all terms (one pixel set keeps the identity
    exact); they are counted in ``nonfinite_pixels`` (union over renders),
    ``nonfinite_pixels_per_seed`` and ``ref_nonfinite_pixels``, and make
    ``finite`` False. MRSE per seed here is therefore over that common pixel
    set. Also returned: ``k``. Averages are None when no pixel is finite everywhere.

    ``images`` is a (K, H, W, C) array or a sequence of (H, W, C) arrays; beyond the
    input it keeps the K weighted errors in float64 (for the Gram matrix).
    """
    renders = _as_render_list(images)
    ref = as_image(ref, "reference image")
    eps = check_eps(eps)
    for x in renders:
        check_same_shape(x, ref)
    k = len(renders)

    ref_ok = _reference_ok(ref, ref_variance)
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
        return {**counts, "rbias2": None, "rbias2_pooled": None, "rbias2_basis": None,
                "rbias2_seed_values": None, "rbias2_ci95": None,
                "rbias2_ci_note": "no interval: no finite pixel", "rvar_seed_values": None,
                "rvar_ci95": None, "rvar_ci_note": "no interval: no finite pixel",
                "rbias2_raw": None, "noise_floor": None,
                "ref_floor": None, "rvar": None, "mrse_mean": None, "mrse_corrected": None,
                "mrse_ci95": None, "mrse_ci_note": "no interval: no finite pixel",
                "mrse_per_seed": None,
                **_floor_report(None, {"rbias2": None, "mrse": None})}

    r = np.asarray(ref[valid], dtype=np.float64)
    w = _relative_weight(r, eps)
    # Two passes over the renders (mean, then deviations): an exact sample variance.
    m = np.zeros_like(r)
    for x in renders:
        m += x[valid]
    m /= k
    sum_sq_dev = np.zeros_like(r)
    mrse_per_seed = []
    # sqrt(w) (X_k - R) per seed, for the Gram matrix of the jackknife intervals.
    weighted_errors = np.empty((k, r.size))
    sqrt_w = np.sqrt(w)
    for index, x in enumerate(renders):
        xk = np.asarray(x[valid], dtype=np.float64)
        sum_sq_dev += (xk - m) ** 2
        weighted_errors[index] = (xk - r).ravel() * sqrt_w.ravel()
        mrse_per_seed.append(float(np.mean(weighted_errors[index] ** 2)))
    s2 = sum_sq_dev / (k - 1)

    rbias2_raw = float(np.mean((m - r) ** 2 * w))
    rvar = float(np.mean(s2 * w))
    noise_floor = rvar / k
    ref_floor = _reference_floor(ref_variance, valid, w)
    rbias2 = rbias2_raw - noise_floor - (ref_floor or 0.0)
    mrse_mean = float(np.mean(mrse_per_seed))
    mrse_ci95, mrse_ci_note = interval_or_reason(mrse_per_seed)
    mrse_corrected = None if ref_floor is None else mrse_mean - ref_floor
    return {
        **counts,
        "rbias2": rbias2,
        "rbias2_pooled": rbias2,
        **pooled_intervals(seed_gram(weighted_errors), rvar, ref_floor or 0.0),
        "rbias2_raw": rbias2_raw,
        "noise_floor": noise_floor,
        "ref_floor": ref_floor,
        "rvar": rvar,
        "mrse_mean": mrse_mean,
        "mrse_corrected": mrse_corrected,
        "mrse_ci95": mrse_ci95,
        "mrse_ci_note": mrse_ci_note,
        "mrse_per_seed": mrse_per_seed,
        **_floor_report(ref_floor, {"rbias2": rbias2, "mrse": mrse_corrected}),
    }


def per_cache_bias_variance(caches: Sequence[MeanEstimate], ref: np.ndarray,
                            eps: float = DEFAULT_EPS,
                            ref_variance: np.ndarray | None = None) -> dict[str, Any]:
    """rBias^2 and rVar of each of K caches from its own F frames (docs/metrics.md).

    Pooling K independently trained caches first (:func:`bias_variance` takes
    the mean over seeds) lets opposite biases cancel. Here cache k contributes
    its frames' per-pixel mean M_k, unbiased variance S_k^2 and count F
    (``caches[k]``: ``mean``, ``variance_of_mean`` = S_k^2 / F, ``count``), and
    with w = 1 / (R^2 + eps), averaged over pixels and channels,

    - rBias^2_k = mean (M_k - R)^2 w - mean S_k^2 / F w - ref_floor
    - rVar_k    = mean S_k^2 w  (the variance of *one frame*)

    Returned: ``rbias2_per_cache`` and ``rvar_per_cache`` (lists), their
    ``_mean``, ``_std`` (sample standard deviation over caches; None for K = 1),
    ``_min`` and ``_max``; ``per_cache_frames`` (F) and
    ``per_cache_excluded_pixels`` (pixels non-finite in the reference or in
    any cache's statistics, left out of every cache so all use one pixel set).

    The estimate is exact for i.i.d. frames (a frozen cache). Frames of a
    cache trained online are not identically distributed, so S_k^2 then also
    holds the drift of the cache over the run. Frames must be independent:
    positively correlated frames (temporal reuse) make S_k^2 / F smaller than
    the variance of M_k, and the difference is reported as bias (for an AR(1)
    sequence with coefficient phi, by about (1 + phi) / (1 - phi) - 1 times the
    variance of an independent mean); callers leave such methods out.

    Raises MetricError when F < 2, the caches differ in F or shape, or no
    pixel is finite everywhere.
    """
    if not caches:
        raise MetricError("per-cache statistics need at least one cache")
    ref = as_image(ref, "reference image")
    eps = check_eps(eps)
    frames = caches[0].count
    if frames < 2:
        raise MetricError(f"per-cache rBias^2/rVar need F >= 2 frames per cache, got F = {frames}")
    if any(c.count != frames for c in caches):
        raise MetricError(f"caches have different frame counts: {[c.count for c in caches]}")
    for c in caches:
        check_same_shape(c.mean, ref)
    valid = np.logical_and.reduce(
        [_reference_ok(ref, ref_variance)]
        + [finite_pixel_mask(c.mean) & finite_pixel_mask(c.variance_of_mean) for c in caches])
    if not valid.any():
        raise MetricError("no pixel is finite in the reference and in every cache's frames")
    r = np.asarray(ref[valid], dtype=np.float64)
    w = _relative_weight(r, eps)
    ref_floor = _reference_floor(ref_variance, valid, w) or 0.0
    rbias2, rvar = [], []
    for c in caches:
        var_of_mean = c.variance_of_mean[valid]
        rbias2.append(float(np.mean(((c.mean[valid] - r) ** 2 - var_of_mean) * w)) - ref_floor)
        rvar.append(float(np.mean(var_of_mean * frames * w)))
    return {
        **_spread("rbias2_per_cache", rbias2),
        **_spread("rvar_per_cache", rvar),
        "per_cache_frames": frames,
        "per_cache_excluded_pixels": int((~valid).sum()),
    }


def _spread(name: str, values: list[float]) -> dict[str, Any]:
    """``name`` (the list), and its ``_mean``, ``_std`` (ddof 1; None for one value), ``_min``, ``_max``."""
    return {
        name: values,
        f"{name}_mean": float(np.mean(values)),
        f"{name}_std": float(np.std(values, ddof=1)) if len(values) > 1 else None,
        f"{name}_min": min(values),
        f"{name}_max": max(values),
    }


def efficiency(mrse: float, seconds_per_frame: float) -> float:
    """1 / (MRSE x time), time being steady-state seconds per frame (higher is better)."""
    for name, value in (("MRSE", mrse), ("seconds per frame", seconds_per_frame)):
        if value is None or not (math.isfinite(value) and value > 0):
            raise MetricError(f"efficiency needs a finite {name} > 0, got {value!r}")
    return 1.0 / (float(mrse) * float(seconds_per_frame))


def psnr_tonemapped(test: np.ndarray, ref: np.ndarray) -> float | None:
    """PSNR in dB of ``test`` against ``ref`` as displayed: higher is better.

    Both images go through the project's tone mapper "clamp + sRGB"
    (:func:`metrics.tonemap.to_display_srgb` at exposure 0: clamp to [0, 1],
    sRGB encoding), then PSNR = 10 log10(1 / MSE) with MSE over all pixels and
    channels of the [0, 1] values, over the pixels finite in both images.
    Identical displays (MSE = 0) and anything above give PSNR_MAX_DB; None when
    no pixel is finite in both.
    """
    test, ref = check_same_shape(test, ref)
    valid = finite_pixel_mask(test) & finite_pixel_mask(ref)
    if not valid.any():
        return None
    squared = _squared_error(to_display_srgb(test)[valid], to_display_srgb(ref)[valid])
    error = float(squared.mean())
    if error <= 10.0 ** (-PSNR_MAX_DB / 10.0):
        return PSNR_MAX_DB
    return 10.0 * math.log10(1.0 / error)
