"""Two render methods of a package outside nirc-bench (its entry points: pyproject.toml).

``example-direct``: direct lighting only, the PT core with paths of at most two
segments (the emitter seen from the camera, and next-event estimation plus the
BSDF-sampled hit of an emitter at the first surface); its reference shares the
depth, so it is unbiased against it. ``example-nirc``: NIRC under another name
and series label, to show a plugin's caching method taking part in sweeps.
Like a built-in module, this one does not import Mitsuba.
"""

from __future__ import annotations

from dataclasses import replace

from pydantic import Field

from renderers.methods import Method, nirc, pt


class DirectParams(pt.PTParams):
    """The PT core's parameters with the depth held to direct lighting."""

    max_depth: int = Field(2, ge=1, le=2, description="2: direct lighting; 1: emitters seen")


DIRECT = Method("example-direct", "direct lighting only (an example method from a package)",
                DirectParams, pt.render, version=1,
                knob=pt.METHOD.knob, label="direct")

SWEPT = replace(nirc.METHOD, name="example-nirc", label="ex-NIRC", comparison=(),
                description="NIRC under another name (an example method from a package)",
                sweep=replace(nirc.METHOD.sweep, label="example NIRC", equal_time_against=None))
