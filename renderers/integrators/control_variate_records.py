"""One render's first-hit samples, kept for the control-variate models' fit.

The control-variate integrator writes, per lane of the render's wavefront, the
sampled direction w, the sample's f / q, its density q (which a model trained on the
residual's variance needs) and whether it counts (a surface hit with
a finite estimate) into lane-indexed buffers: plain scatters, one slot per lane,
executed with the render's kernel. A model reduces them per pixel between frames
(:meth:`SampleRecords.per_pixel_sum`): Mitsuba lays a wavefront out pixel-major
(the spp samples of a pixel are consecutive lanes; renderers.integrators.cached.
pixel_index), so a pixel's samples are one block, and a block sum adds them in a
fixed order. Accumulating with float atomics during the render instead would add
them in the order the threads run, and a render would not repeat bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np


@dataclass
class SampleRecords:
    """The samples of one render, one lane each (module docstring)."""

    w: mi.Vector3f            # the sampled world-space direction
    weighted: mi.Spectrum     # f(w) / q(w); 0 where no direction was produced
    counts: mi.Float          # 1 where the lane's sample enters the fit, else 0
    nonfinite: mi.Float       # 1 where a hit's estimate was NaN or infinite (left out)
    pdf: mi.Float             # q(w); 0 where no direction was produced
    spp: int

    @staticmethod
    def write(w: mi.Vector3f, weighted: mi.Spectrum, pdf: mi.Float, hit: mi.Bool,
              spp: int) -> SampleRecords:
        """Scatter one render's lanes into buffers of their own (called in ``sample``)."""
        lanes = dr.width(hit)
        lane = dr.arange(mi.UInt32, lanes)
        finite = dr.all(dr.isfinite(weighted))

        def kept(value: mi.Float) -> mi.Float:
            buffer = dr.zeros(mi.Float, lanes)
            dr.scatter(buffer, value, lane)
            return buffer

        counted = hit & finite
        w = dr.select(hit, w, mi.Vector3f(0, 0, 1))   # a miss has no direction
        return SampleRecords(
            w=mi.Vector3f(*(kept(w[i]) for i in range(3))),
            weighted=mi.Spectrum(*(kept(dr.select(counted, weighted[c], 0.0))
                                   for c in range(3))),
            counts=kept(dr.select(counted, 1.0, 0.0)),
            nonfinite=kept(dr.select(hit & ~finite, 1.0, 0.0)),
            pdf=kept(dr.select(counted, pdf, 0.0)),
            spp=spp)

    def arrays(self) -> tuple[mi.Vector3f, mi.Spectrum, mi.Float, mi.Float, mi.Float]:
        """The buffers, e.g. as a frozen render's outputs (:meth:`of` takes them back)."""
        return self.w, self.weighted, self.counts, self.nonfinite, self.pdf

    @classmethod
    def of(cls, arrays: tuple[mi.Vector3f, mi.Spectrum, mi.Float, mi.Float, mi.Float],
           spp: int) -> SampleRecords:
        return cls(*arrays, spp=spp)

    @property
    def pixel(self) -> mi.UInt32:
        """Each lane's pixel."""
        return dr.arange(mi.UInt32, dr.width(self.counts)) // self.spp

    def per_pixel_sum(self, value: mi.Float) -> mi.Float:
        """The sum of ``value`` over each pixel's lanes, in lane order."""
        return dr.block_sum(value, self.spp)

    def nonfinite_count(self) -> int:
        return int(dr.sum(self.nonfinite)[0])

    def residuals(self, model: Any, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        """Each lane's residual sample of Eq. 7 with ``model``'s g, (f(w) - g_p(w)) / q(w)
        (0 where no direction was produced, NaN where the estimate was not finite), as
        (H, W, spp, 3) values (float64) and (H, W, spp) the lanes that hit a surface."""
        produced = self.pdf > 0
        g = model.eval(self.pixel, self.w, produced)
        residual = dr.select(produced, self.weighted - g / dr.select(produced, self.pdf, 1.0),
                             0.0)
        shape = (height, width, self.spp)
        values = np.moveaxis(np.array(residual, dtype=np.float64), 0, -1).reshape(*shape, 3)
        nonfinite = np.array(self.nonfinite, dtype=np.float64).reshape(shape) > 0
        values[nonfinite] = np.nan
        probed = (np.array(self.counts, dtype=np.float64).reshape(shape) > 0) | nonfinite
        return values, probed
