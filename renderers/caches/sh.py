"""Per-pixel spherical-harmonics model of the shading integrand, a control variate
with a closed-form integral (NIRC paper Sec. 6.1: the SH control variate of Fig. 6).

Each pixel p holds, per colour channel, the coefficients c_k(p) of the real,
orthonormal SH basis Y_k (``dr.sh_eval``, Sloan's convention) of ``bands`` bands,
K = bands^2 coefficients, and the model is

    g_p(w) = sum_k c_k(p) Y_k(w),            w a world-space unit direction.

Its integral over the sphere is closed-form: the Y_k with l > 0 integrate to 0 and
Y_0 = 1 / (2 sqrt(pi)) is constant, so

    G_p = int_S2 g_p dw = c_0(p) * 4 pi / (2 sqrt(pi)) = 2 sqrt(pi) c_0(p).

Fitting (projection, the least-squares fit of an orthonormal basis: the minimiser of
int_S2 (f - g)^2, the expectation of the L2 loss of NIRC Eq. 17): with samples
w_j ~ q of the integrand f(w) (incident radiance x BSDF x cosine at the pixel's
primary hit) and their estimates f_j,

    c_k(p) = int_S2 f Y_k dw  ~=  1/N_p sum_j f_j Y_k(w_j) / q(w_j),

summed over *every* sample of the pixel so far: :meth:`SHModel.fit` adds one
render's samples (renderers.integrators.control_variate_records) between frames,
so a frame's g is fitted from earlier frames' samples only, never from the samples
whose residual it controls (docs/control_variates.md).
"""

from __future__ import annotations

import math
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

#: ``dr.sh_eval`` evaluates orders 0..10, i.e. up to 11 bands.
MAX_BANDS = 11
#: int_S2 Y_0 dw (Y_0 = 1 / (2 sqrt(pi)) on the whole sphere).
Y0_INTEGRAL = 2.0 * math.sqrt(math.pi)
CHANNELS = 3


class SHConfig(BaseModel):
    """The per-pixel SH model: ``bands`` bands, bands^2 coefficients per channel
    (5 bands: 25, i.e. 75 floats per pixel, the paper's equal-memory preset)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    bands: int = Field(5, ge=1, le=MAX_BANDS, description="SH bands (bands^2 coefficients)")

    @property
    def coefficients(self) -> int:
        return self.bands * self.bands

    def floats_per_pixel(self) -> dict[str, int]:
        """The model's floats per pixel (what g is), and the fit's running sums and
        sample count, kept besides (a render's samples add 9 floats per sample until
        the fit: renderers.integrators.control_variate_records)."""
        return {"model": CHANNELS * self.coefficients,
                "fit": CHANNELS * self.coefficients + 1}


def sh_config(**overrides: Any) -> SHConfig:
    """The SH preset with ``overrides`` (a method's ``sh`` parameter)."""
    return SHConfig(**overrides)


class SHModel:
    """The per-pixel SH coefficients of ``pixels`` pixels (module docstring), zero
    until the first :meth:`fit`: g = 0, the plain estimator. Arrays per coefficient
    k and channel c, indexed by pixel. Its frames may be frozen (renderers.frozen)."""

    freezable = True

    def __init__(self, config: SHConfig, pixels: int) -> None:
        import drjit as dr
        import mitsuba as mi

        self.config = config
        self.pixels = pixels
        shape = (config.coefficients, CHANNELS)
        self.coefficients = [[dr.zeros(mi.Float, pixels) for _ in range(shape[1])]
                             for _ in range(shape[0])]
        self.sums = [[dr.zeros(mi.Float, pixels) for _ in range(shape[1])]
                     for _ in range(shape[0])]
        self.counts = dr.zeros(mi.Float, pixels)
        #: Samples left out of the fit because their estimate was NaN or infinite.
        self.nonfinite = 0

    def state(self) -> dict[str, Any]:
        """The Dr.Jit data a render reads (a frozen render's argument, renderers.frozen)."""
        return {"coefficients": self.coefficients}

    def bind(self, state: dict[str, Any]) -> None:
        """Read :meth:`state`'s data from ``state``."""
        self.coefficients = state["coefficients"]

    def _basis(self, w: Any) -> list[Any]:
        import drjit as dr

        return dr.sh_eval(w, self.config.bands - 1)

    def eval(self, pixel: Any, w: Any, active: Any) -> Any:
        """g_p(w) per channel (a Spectrum)."""
        import drjit as dr
        import mitsuba as mi

        value = [mi.Float(0.0) for _ in range(CHANNELS)]
        for y_k, coefficients in zip(self._basis(w), self.coefficients, strict=True):
            for c in range(CHANNELS):
                value[c] += y_k * dr.gather(mi.Float, coefficients[c], pixel, active)
        return mi.Spectrum(*value)

    def integral(self, pixel: Any, active: Any) -> Any:
        """G_p = 2 sqrt(pi) c_0(p) (module docstring), per channel."""
        import drjit as dr
        import mitsuba as mi

        return mi.Spectrum(*[Y0_INTEGRAL * dr.gather(mi.Float, self.coefficients[0][c],
                                                      pixel, active)
                             for c in range(CHANNELS)])

    def fit(self, records: Any) -> None:
        """Add one render's samples (f_j / q(w_j) at w_j; 0 for a direction not
        produced, which still counts) to the running sums; c_k = sums / count."""
        import drjit as dr

        for y_k, sums in zip(self._basis(records.w), self.sums, strict=True):
            for c in range(CHANNELS):
                sums[c] += records.per_pixel_sum(y_k * records.weighted[c])
        self.counts += records.per_pixel_sum(records.counts)
        self.nonfinite += records.nonfinite_count()
        samples = dr.maximum(self.counts, 1.0)
        self.coefficients = [[total / samples for total in sums] for sums in self.sums]
        dr.eval(self.coefficients, self.sums, self.counts)

    def stats(self) -> dict[str, Any]:
        """What a run stores of the model: its config, floats per pixel, the samples
        each pixel's fit holds on average and the non-finite samples left out."""
        import numpy as np

        return {"config": self.config.model_dump(mode="json"),
                "floats_per_pixel": self.config.floats_per_pixel(),
                "fit_samples_per_pixel": float(np.mean(np.asarray(self.counts))),
                "nonfinite_samples": self.nonfinite}
