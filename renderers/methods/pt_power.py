"""`pt-power`: the PT core with emitters selected in proportion to their power.

The light sampler is :class:`renderers.integrators.lights.PowerLightSampler`
(pbrt-v4's ``PowerLightSampler``): p(i) ∝ Φ_i, Φ_i ≈ π · area · mean
luminance of an area emitter (4π² R² · mean luminance for an environment),
computed once per scene. It drives NEE and the MIS weight of BSDF-sampled
emitter hits alike, so the estimator stays unbiased (docs/estimators.md,
"Light selection").
"""

from __future__ import annotations

from renderers.methods import register
from renderers.methods.base import Knob, Method
from renderers.methods.pt import SPP_CANDIDATES, PTParams, render_with_lights


class PTPowerParams(PTParams):
    """The path-tracing core's parameters; the selector has none of its own."""


render = render_with_lights("PowerLightSampler")


METHOD = register(Method("pt-power", "path tracing with emitters selected in proportion to power",
                PTPowerParams, render, version=1,
                knob=Knob("spp", SPP_CANDIDATES), unbiased=True))
