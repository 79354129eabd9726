"""The project's one display transform: linear RGB -> sRGB-encoded values in [0, 1].

Tone mapper ("clamp + sRGB"): multiply by 2^exposure (exposure in stops),
set non-finite pixels to 0, clamp to [0, 1], then apply the sRGB encoding
(IEC 61966-2-1 OETF) with ``colour.cctf_encoding(..., function="sRGB")``.
Used by PNG previews and by LDR-FLIP, so what a preview shows is what LDR-FLIP
compares.
"""

from __future__ import annotations

import warnings
from functools import cache
from types import ModuleType

import numpy as np

from metrics.checks import as_image, zero_nonfinite


@cache
def _colour() -> ModuleType:
    """colour-science, imported on first use.

    Lazy because importing ``colour`` without SciPy/Matplotlib installed warns
    about them and puts ``MagicMock`` modules into ``sys.modules['scipy']`` and
    ``sys.modules['matplotlib']``; processes that never make a preview should
    not pay for (or be affected by) that. The warnings concern features we do
    not use, so they are silenced.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour
    return colour


def to_display_srgb(img: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """(H, W, C) float32 sRGB-encoded image in [0, 1] (see the module docstring)."""
    linear = zero_nonfinite(as_image(img)) * np.float32(2.0 ** exposure)
    np.clip(linear, 0.0, 1.0, out=linear)
    encoded = _colour().cctf_encoding(linear, function="sRGB")
    # Clip again: the encoding of 1.0 may round a hair above 1 in float64.
    return np.clip(encoded, 0.0, 1.0).astype(np.float32)
