"""Per-pixel relative bias and variance of a run's K seeds: the maps behind rBias² and rVar.

With the seeds' per-pixel mean M, their unbiased sample variance S² and the MRSE
weight w = 1 / (R² + eps) (metrics.errors.bias_variance), per pixel and channel:

- the relative-bias map  b = (M - R) sqrt(w): signed (red where the method is too
  bright, blue where too dark in the comparison view); mean b² is ``rbias2_raw``;
- the relative-variance map  v = S² w: mean v is ``rvar``.

So the maps show where the run's rBias² and rVar come from. A pixel that is not
finite in the reference or in any seed is NaN in both maps. Both are float32 (H, W, C).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from metrics.checks import check_eps, check_same_shape


def relative_bias_variance_maps(images: Sequence[np.ndarray], ref: np.ndarray,
                                eps: float) -> tuple[np.ndarray, np.ndarray]:
    """(relative-bias map, relative-variance map) of K >= 2 renders against ``ref``."""
    if len(images) < 2:
        raise ValueError(f"a variance map needs K >= 2 renders, got K = {len(images)}")
    eps = check_eps(eps)
    for image in images:
        check_same_shape(image, ref)
    r = np.asarray(ref, dtype=np.float64)
    w = 1.0 / (r * r + eps)
    with np.errstate(invalid="ignore", over="ignore"):
        stack = np.stack([np.asarray(x, dtype=np.float64) for x in images])
        mean = stack.mean(axis=0)
        variance = stack.var(axis=0, ddof=1)
        bias = (mean - r) * np.sqrt(w)
        spread = variance * w
    bad = ~(np.isfinite(stack).all(axis=0) & np.isfinite(r))
    bias[bad] = np.nan
    spread[bad] = np.nan
    return bias.astype(np.float32), spread.astype(np.float32)
