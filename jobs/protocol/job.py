"""One render job, parsed once: the validated spec and its method's typed parameters.

A :class:`~jobs.protocol.spec.RenderSpec` carries the method's parameters as
JSON (``params``), which is what is stored, hashed into keys and sent over the
wire. Everything that renders needs them as the method's parameter model. A
:class:`RenderJob` holds both, made once where a job enters (the REST route,
the CLI, the runner taking a job from the database, the sweep, Pareto, report,
stress and CI expansions) by :meth:`RenderJob.parse`, and passed down: the
executor, the calibration and ``store_run`` read ``job.params`` and never
parse the JSON again. A job derived from another (a calibrated knob value, the
PT job a time budget is measured against) is made here as well.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from jobs.protocol.spec import RenderSpec
from renderers.methods import (
    BASELINE,
    MethodParams,
    parse_params,
)
from renderers.methods.pt import DEFAULT_MAX_DEPTH


@dataclass(frozen=True)
class RenderJob:
    """A render spec with its method's validated parameter model (frozen, both)."""

    spec: RenderSpec
    params: MethodParams

    @classmethod
    def parse(cls, spec: RenderSpec | Mapping[str, Any]) -> RenderJob:
        """The job of ``spec`` (a spec, or its JSON as stored): the one place a render
        spec's parameters are validated by the method's model (strictly, as
        everywhere: a string or a boolean is not a number)."""
        if not isinstance(spec, RenderSpec):
            spec = RenderSpec.model_validate(dict(spec))
        return cls(spec, parse_params(spec.method, spec.params))

    @property
    def method(self) -> str:
        return self.spec.method

    @property
    def max_depth(self) -> int:
        """The method's path depth, which its reference must share (the parameters' or
        the default of the method's model; `restir-di`: 2, direct light only)."""
        return int(getattr(self.params, "max_depth", DEFAULT_MAX_DEPTH))

    def key(self) -> str:
        """The spec's content address (:meth:`RenderSpec.key`)."""
        return self.spec.key()

    def with_spec(self, **update: Any) -> RenderJob:
        """This job with spec fields other than ``params`` changed (spp, budget)."""
        if "params" in update or "method" in update:
            raise ValueError("a job's method and parameters change with with_params")
        return RenderJob(self.spec.model_copy(update=update), self.params)

    def with_params(self, params: Mapping[str, Any]) -> RenderJob:
        """A job derived from this one with other parameters (JSON, e.g. a knob value
        the method's ``Knob.apply`` set), validated by the method's model."""
        derived = self.spec.model_copy(update={"params": dict(params)})
        return RenderJob(derived, parse_params(derived.method, derived.params))

    def baseline(self) -> RenderJob:
        """The baseline method's job at this job's depth (what a PT budget measures)."""
        derived = self.spec.model_copy(update={"method": BASELINE,
                                               "params": {"max_depth": self.max_depth}})
        return RenderJob(derived, parse_params(BASELINE, derived.params))

    @classmethod
    def of(cls, spec: RenderSpec, params: MethodParams) -> RenderJob:
        """The job of an expansion that validated ``params`` itself (a sweep point):
        ``spec.params`` must be their dump."""
        if spec.params != params.model_dump(mode="json"):
            raise ValueError("the spec's params are not the dump of the typed parameters")
        return cls(spec, params)
