"""`pt-spatial`: the PT core with emitters selected per shading point.

The light sampler is :class:`renderers.integrators.lights.SpatialLightSampler`:
p(i | x) ∝ Φ_i / max(|x - c_i|^2, r_i^2) with Φ_i the emitter's approximate
power, c_i its bounding-box centre and r_i its half diagonal (the distance
term of pbrt-v4's ``BVHLightSampler`` importance, without the tree). The MIS
weight of a BSDF-sampled emitter hit uses the pmf at the previous vertex, the
one NEE there would have used (docs/estimators.md, "Light selection").
"""

from __future__ import annotations

from renderers.methods import register
from renderers.methods.base import Knob, Method
from renderers.methods.pt import SPP_CANDIDATES, PTParams, render_with_lights


class PTSpatialParams(PTParams):
    """The path-tracing core's parameters; the selector has none of its own."""


render = render_with_lights("SpatialLightSampler")


METHOD = register(Method("pt-spatial", "path tracing with emitters selected by power / distance^2 per shading point",
                PTSpatialParams, render, version=1,
                knob=Knob("spp", SPP_CANDIDATES), unbiased=True))
