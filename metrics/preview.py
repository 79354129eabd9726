"""8-bit RGB previews for the dashboard and exports (write them with ``imageio.write_png``).

- :func:`tonemap_preview`: an HDR image through the project's tone mapper
  "clamp + sRGB" (:func:`metrics.tonemap.to_display_srgb`: 2^exposure, clamp
  to [0, 1], sRGB encoding), quantised to uint8.
- :func:`error_map_preview`: a scalar error map (relative squared error,
  FLIP, ...) through the perceptually uniform *magma* colormap, without
  Matplotlib.
"""

from __future__ import annotations

import numpy as np

from metrics.checks import MetricError, as_image
from metrics.tonemap import to_display_srgb

# Every 16th entry (plus the last) of the 256-entry magma colormap by
# S. van der Walt and N. Smith (CC0), as shipped in Matplotlib; linear
# interpolation between them is visually indistinguishable from the full table.
_MAGMA_POSITIONS = np.array([0, 16, 32, 48, 64, 80, 96, 112, 128, 144, 160, 176, 192, 208,
                             224, 240, 255]) / 255.0
_MAGMA_COLOURS = np.array([
    [0.001462, 0.000466, 0.013866],
    [0.039608, 0.031090, 0.133515],
    [0.113094, 0.065492, 0.276784],
    [0.211718, 0.061992, 0.418647],
    [0.316654, 0.071690, 0.485380],
    [0.414709, 0.110431, 0.504662],
    [0.512831, 0.148179, 0.507648],
    [0.613617, 0.181811, 0.498536],
    [0.716387, 0.214982, 0.475290],
    [0.816914, 0.255895, 0.436461],
    [0.904281, 0.319610, 0.388137],
    [0.960949, 0.418323, 0.359630],
    [0.986700, 0.535582, 0.382210],
    [0.996096, 0.653659, 0.446213],
    [0.996898, 0.769591, 0.534892],
    [0.992440, 0.884330, 0.640099],
    [0.987053, 0.991438, 0.749504],
])


def _to_uint8(unit: np.ndarray) -> np.ndarray:
    return np.rint(np.clip(unit, 0.0, 1.0) * 255.0).astype(np.uint8)


def tonemap_preview(img: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """(H, W, 3) uint8 sRGB preview of a linear HDR image (grey is replicated, alpha dropped).

    Tone mapper: x 2^exposure, clamp to [0, 1], sRGB OETF; non-finite pixels
    show black.
    """
    arr = as_image(img)
    if arr.shape[2] == 1:
        arr = np.repeat(arr, 3, axis=2)
    elif arr.shape[2] == 4:
        arr = arr[..., :3]  # previews are opaque: drop alpha
    elif arr.shape[2] != 3:
        raise MetricError(f"a preview needs 1, 3 or 4 channels, got shape {arr.shape}")
    return _to_uint8(to_display_srgb(arr, exposure))


def colormap_magma(values: np.ndarray) -> np.ndarray:
    """float32 (..., 3) magma colours of ``values`` in [0, 1] (clamped)."""
    v = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
    channels = [np.interp(v, _MAGMA_POSITIONS, _MAGMA_COLOURS[:, c]) for c in range(3)]
    return np.stack(channels, axis=-1).astype(np.float32)


def error_map_preview(error_map: np.ndarray, vmax: float = 1.0) -> np.ndarray:
    """(H, W, 3) uint8 magma rendering of an (H, W) or (H, W, 1) error map.

    Values are shown on the scale [0, ``vmax``] (clamped above). Non-finite
    values are painted at the top of the scale: a NaN error is as bad as it gets.
    """
    arr = np.asarray(error_map, dtype=np.float64)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    if arr.ndim != 2:
        raise MetricError(f"an error map must be (H, W) or (H, W, 1), got shape {arr.shape}")
    if not (np.isfinite(vmax) and vmax > 0):
        raise MetricError(f"vmax must be a finite number > 0, got {vmax}")
    unit = np.where(np.isfinite(arr), arr / vmax, 1.0)
    return _to_uint8(colormap_magma(unit))
