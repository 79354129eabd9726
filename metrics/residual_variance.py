"""V_rel(<F_r>): the relative variance of the residual estimator at the primary hit
(NIRC paper Sec. 4.1 Eq. 14, Sec. 6.1 Fig. 6); the definition is in docs/metrics.md.

Per pixel p and channel c, S²_pc is the unbiased sample variance of the n_p >= 2
residual samples of the pixel (renderers.integrators.residual_probe: one per path
whose primary hit used the cache, all with the run's final cache), an estimate of
Eq. 14's V(<F_r>) for the pixel's surface; V_rel is its mean relative to the
reference, with the weight of MRSE:

    V_rel = mean_{p, c} S²_pc / (R_pc² + eps)

over the pixels with n_p >= 2 whose samples and reference are finite.
"""

from __future__ import annotations

import numpy as np


def residual_variance_map(values: np.ndarray, probed: np.ndarray) -> tuple[np.ndarray, int]:
    """Per pixel and channel the sample variance S² (ddof 1, float64) of the probed samples
    (``values`` (H, W, n, 3), ``probed`` (H, W, n)); NaN where a pixel has fewer than
    two probed samples or a non-finite one. Also the count of non-finite probed samples."""
    values = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(values).all(axis=-1)
    nonfinite = int(np.count_nonzero(probed & ~finite))
    usable = probed & finite
    count = usable.sum(axis=-1)[..., None]
    samples = np.where(usable[..., None], values, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = samples.sum(axis=-2) / count
        squares = np.where(usable[..., None], (values - mean[..., None, :]) ** 2, 0.0)
        variance = squares.sum(axis=-2) / (count - 1)
    unusable = (count < 2) | (probed & ~finite).any(axis=-1)[..., None]
    # float64: radiance scaled by 1e6 has squared deviations past float32's range
    return np.where(unusable, np.nan, variance), nonfinite


def relative_residual_variance(variance: np.ndarray, reference: np.ndarray,
                               eps: float) -> float | None:
    """V_rel: mean of S² / (R² + eps) over the pixels and channels where both are finite;
    None where there is none (no pixel had two residual samples)."""
    weighted = variance / (np.square(reference.astype(np.float64)) + eps)
    usable = np.isfinite(weighted)
    return float(weighted[usable].mean()) if usable.any() else None
