"""The project's one display transform: linear RGB -> sRGB-encoded values in [0, 1].

Tone mapper ("clamp + sRGB"): multiply by 2^exposure (exposure in stops),
set non-finite pixels to 0, clamp to [0, 1], then apply the sRGB encoding
(IEC 61966-2-1 OETF, :func:`srgb_encode`). Used by PNG previews and by LDR-FLIP,
so what a preview shows is what LDR-FLIP compares.
"""

from __future__ import annotations

import numpy as np

from metrics.checks import as_image, zero_nonfinite

#: Linear values up to this are encoded by the linear segment (IEC 61966-2-1).
SRGB_LINEAR_LIMIT = 0.0031308


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB encoding of linear values in [0, 1], in float64 (IEC 61966-2-1:1999):
    V = 12.92 L for L <= 0.0031308, else 1.055 L^(1/2.4) - 0.055.

    Written term for term as colour-science's ``cctf_encoding(..., function="sRGB")``,
    the project's encoder before (importing that package loads Matplotlib and SciPy:
    seconds in every process that scores a render), so the values are bitwise the same:
    compared for every float32 in [0, 1] when it was written, and on a sample of them
    by tests/metrics/test_preview.py."""
    values = np.asarray(linear, dtype=np.float64)
    return np.where(values <= SRGB_LINEAR_LIMIT, values * 12.92,
                    1.055 * values ** (1 / 2.4) - 0.055)


def to_display_srgb(img: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """(H, W, C) float32 sRGB-encoded image in [0, 1] (see the module docstring)."""
    linear = zero_nonfinite(as_image(img)) * np.float32(2.0 ** exposure)
    np.clip(linear, 0.0, 1.0, out=linear)
    encoded = srgb_encode(linear)
    # Clip again: the encoding of 1.0 may round a hair above 1 in float64.
    return np.clip(encoded, 0.0, 1.0).astype(np.float32)
