"""Per-pixel relative-bias maps of a converged image V against a reference R.

The adaptive equal-bias protocol (NIRC paper Sec. 6.3) lets a pixel use the
cache at its first vertex when the relative bias of the converged
cache-at-v1 image V is below a threshold. Both V and R are Monte Carlo
estimates, so their difference carries their noise as well as the bias:
E[(V - R)^2] = bias^2 + Var[V] + Var[R] for independent V and R. Every map
here subtracts the two variances of the mean (when given) from the squared
difference before it is turned into a relative bias, so that a noisy but
unbiased V does not look biased.

Two definitions, both a map b with "the pixel passes at eps" meaning b < eps
(:func:`passes`):

- ``relative-mse`` (the project's default): the root of the pixel's
  relative squared error as in MRSE, with the noise removed,
  b_p^2 = max(0, mean_c [(V - R)^2 - Var[V] - Var[R]] / (R^2 + e)),
  e the metric epsilon. Its square is the pixel's term of rBias^2.
- ``authors``: the test of the authors' public implementation, per channel
  |V_c - R_c| / luminance(R) (Rec. 601 weights 0.299, 0.587, 0.114), every
  channel must pass; here with the noise removed from the squared
  difference, d_c = sqrt(max(0, (V_c - R_c)^2 - Var[V_c] - Var[R_c])), and
  b_p = max_c d_c / luminance(R), so b_p < eps means every channel passes.
  A pixel whose reference luminance is <= ``LUMINANCE_FLOOR`` never passes
  (b_p = inf): the ratio is undefined there. (The authors divide by the
  luminance of V, not of R, and have no such guard.)

Non-finite inputs give a NaN map entry, which never passes. Everything is
computed in float64 and returned as float32 (H, W) maps.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

#: The definitions :func:`bias_map` knows.
BiasDefinition = Literal["relative-mse", "authors"]
BIAS_DEFINITIONS: tuple[str, ...] = ("relative-mse", "authors")

#: Rec. 601 luminance weights (those of the authors' implementation).
LUMINANCE_WEIGHTS = np.array([0.299, 0.587, 0.114])

#: At or below this reference luminance the ``authors`` ratio is undefined: the pixel fails.
LUMINANCE_FLOOR = 1e-8


def _noise_free_squared_difference(v: np.ndarray, ref: np.ndarray,
                                   v_variance: np.ndarray | None,
                                   ref_variance: np.ndarray | None) -> np.ndarray:
    """(V - R)^2 - Var[V] - Var[R] per channel, float64 (may be negative: the caller clips)."""
    v = np.asarray(v, dtype=np.float64)[..., :3]
    r = np.asarray(ref, dtype=np.float64)[..., :3]
    if v.shape != r.shape:
        raise ValueError(f"image shape {v.shape} does not match the reference's {r.shape}")
    squared = (v - r) ** 2
    for variance in (v_variance, ref_variance):
        if variance is not None:
            variance = np.asarray(variance, dtype=np.float64)[..., :3]
            if variance.shape != r.shape:
                raise ValueError(f"variance shape {variance.shape} does not match the "
                                 f"image's {r.shape}")
            squared = squared - variance
    return squared


def relative_mse_bias_map(v: np.ndarray, ref: np.ndarray, eps: float,
                          v_variance: np.ndarray | None = None,
                          ref_variance: np.ndarray | None = None) -> np.ndarray:
    """b_p = sqrt(max(0, mean_c [(V-R)^2 - Var V - Var R] / (R^2 + eps))) (module doc).

    Without variances this is the root of the pixel's relative squared error.
    """
    if not eps > 0:
        raise ValueError(f"eps must be positive, got {eps}")
    with np.errstate(invalid="ignore", over="ignore"):
        squared = _noise_free_squared_difference(v, ref, v_variance, ref_variance)
        r = np.asarray(ref, dtype=np.float64)[..., :3]
        per_pixel = np.mean(squared / (r * r + eps), axis=-1)
        return np.sqrt(np.maximum(per_pixel, 0.0)).astype(np.float32)


def authors_bias_map(v: np.ndarray, ref: np.ndarray,
                     v_variance: np.ndarray | None = None,
                     ref_variance: np.ndarray | None = None) -> np.ndarray:
    """b_p = max_c sqrt(max(0, (V_c-R_c)^2 - Var V_c - Var R_c)) / luminance(R) (module doc);
    inf where luminance(R) <= LUMINANCE_FLOOR."""
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        squared = _noise_free_squared_difference(v, ref, v_variance, ref_variance)
        # np.maximum and np.max propagate NaN: a non-finite channel keeps the pixel NaN.
        worst = np.sqrt(np.max(np.maximum(squared, 0.0), axis=-1))
        lum = np.asarray(ref, dtype=np.float64)[..., :3] @ LUMINANCE_WEIGHTS
        ratio = np.where(lum > LUMINANCE_FLOOR, worst / np.where(lum > 0, lum, 1.0), np.inf)
        ratio = np.where(np.isnan(worst) | np.isnan(lum), np.nan, ratio)
        return ratio.astype(np.float32)


def bias_map(definition: str, v: np.ndarray, ref: np.ndarray, eps: float,
             v_variance: np.ndarray | None = None,
             ref_variance: np.ndarray | None = None) -> np.ndarray:
    """The per-pixel relative bias of ``definition`` (``eps``: the metric epsilon of
    ``relative-mse``; unused by ``authors``)."""
    if definition == "relative-mse":
        return relative_mse_bias_map(v, ref, eps, v_variance, ref_variance)
    if definition == "authors":
        return authors_bias_map(v, ref, v_variance, ref_variance)
    raise ValueError(f"unknown bias definition {definition!r}; "
                     f"known: {', '.join(BIAS_DEFINITIONS)}")


def passes(bias: np.ndarray, threshold: float) -> np.ndarray:
    """Pixels whose relative bias is below ``threshold`` (NaN never passes)."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(bias) & (bias < threshold)
