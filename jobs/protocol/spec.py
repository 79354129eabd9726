"""Job specifications: what a render job is, validated before anything runs.

A spec is plain data (pydantic): the CLI builds one from its options, the REST
API from a request body; the executor runs it. Out-of-range values are
rejected here with a message naming the field. Specs are strict: a JSON string
or boolean is not a number, and no number is NaN or infinite (method
parameters included: their JSON is checked here, their fields by the method).
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    ValidationInfo,
    field_validator,
    model_serializer,
    model_validator,
)

from jobs.protocol.ranges import parse_range
from jobs.protocol.versions import sweep_estimator_versions, versions_of
from metrics import METRIC_VERSION
from renderers.methods import (
    BASELINE,
    METHODS,
    MethodError,
    equal_time_pairs,
    parse_params,
    sweep_methods,
)
from renderers.methods.pt import DEFAULT_MAX_DEPTH
from renderers.reference import ReferenceSettings
from renderers.scenes.animation import Animation
from renderers.seeding import digest


def _non_finite(value: Any, where: str) -> str | None:
    """The first NaN or infinite number in ``value`` (JSON), named by its dotted path."""
    if isinstance(value, float) and not math.isfinite(value):
        return where
    items = (value.items() if isinstance(value, dict)
             else enumerate(value) if isinstance(value, list) else ())
    for key, item in items:
        found = _non_finite(item, f"{where}.{key}")
        if found:
            return found
    return None


def finite_params(params: dict[str, Any]) -> dict[str, Any]:
    """Method parameters (free-form JSON here, the method's model checks its fields)
    with no NaN or infinity anywhere, cache overrides included."""
    where = _non_finite(params, "params")
    if where:
        raise ValueError(f"{where} must be a finite number (NaN and Infinity are not)")
    return params


#: What a spec's ``scene`` may be (docs/service.md has the REST rules).
SCENE_DESCRIPTION = ("built-in scene name, an uploaded scene's id (upload:<digest>), or the path "
                     "of a Mitsuba XML (over REST: under the service's scene roots)")


class ReferenceSpec(BaseModel):
    """How the converged reference of a job is rendered (see renderers.reference)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    integrator: Literal["path", "pt"] = "path"
    spp: int = Field(4096, ge=8, le=1 << 24)
    spp_per_pass: int = Field(64, ge=1, le=1 << 16)
    rel_stderr: float | None = Field(None, gt=0.0, le=1.0)

    def settings(self, max_depth: int) -> ReferenceSettings:
        return ReferenceSettings(integrator=self.integrator, max_depth=max_depth, spp=self.spp,
                                 spp_per_pass=self.spp_per_pass, rel_stderr=self.rel_stderr)


class TimeBudget(BaseModel):
    """Equal time: the frame-time budget a job's knob (PT spp, NIRC N_c) is calibrated to.

    Either ``ms`` per frame, or ``pt_spp``: the frame time of PT at that spp on
    this device, measured now (in every round, interleaved with the candidates).
    The candidates are timed in ``rounds`` interleaved rounds (not those predicted
    over 4x the budget plus its tolerance, nor, for spp, those above one clearly over it); the largest
    whose median fits (within ``tolerance_ms``) is used; the calibration, with its
    spread and its ``capped`` / ``unstable`` flags, is stored with the run
    (jobs.protocol.calibration).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    ms: float | None = Field(None, gt=0.0, le=1e7, description="milliseconds per frame")
    pt_spp: int | None = Field(None, ge=1, le=1 << 16, description="as PT at this spp")
    candidates: list[int] | None = Field(
        None, description="knob values to try (default: 1, 2, 4, ... per method)")
    probe_frames: int = Field(3, ge=1, le=1000, description="timed frames per probe")
    tolerance_ms: float = Field(0.0, ge=0.0, le=1e6)
    rounds: int = Field(3, ge=1, le=100, description="interleaved timing rounds (medians)")
    max_spread: float = Field(
        0.1, gt=0.0, le=10.0, description="spread (max - min over rounds) allowed before the "
                                          "calibration is flagged unstable, x the budget")
    allow_loaded: bool = Field(
        False, description="use probes timed on a loaded machine; by default such a probe "
                           "is left out and taken again, and the calibration stops when "
                           "every try is loaded")

    @model_validator(mode="after")
    def _one_budget(self) -> TimeBudget:
        if (self.ms is None) == (self.pt_spp is None):
            raise ValueError("give exactly one of ms and pt_spp")
        if self.candidates is not None and (
                not self.candidates or min(self.candidates) < 1 or max(self.candidates) > 1 << 16):
            raise ValueError("candidates must be positive integers")
        return self


def keyed_budget(data: dict[str, Any]) -> dict[str, Any]:
    """A dumped spec as its keys see it: a time budget or a sweep that leaves loaded
    probes out (the default) keeps the keys from before ``allow_loaded`` existed."""
    for holder in (data.get("time_budget"), data):
        if holder and not holder.get("allow_loaded", True):
            holder.pop("allow_loaded")
    return data


#: Whether a render job scores its frames after denoising unless told (docs/metrics.md,
#: "Denoised error": what it costs).
DENOISED_DEFAULT = False


class RenderSpec(BaseModel):
    """One render job: a method on a scene, K seeds, compared with a reference."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    scene: str = Field(min_length=1, description=SCENE_DESCRIPTION)
    method: str = BASELINE
    params: dict[str, Any] = Field(default_factory=dict)
    resolution: int = Field(64, ge=1, le=8192, description="image width and height in pixels")
    spp: int = Field(1, ge=1, le=1 << 16, description="samples per pixel per frame")
    frames: int = Field(1, ge=1, le=100_000)
    seeds: int = Field(4, ge=1, le=1000, description="K independent renders (rBias2/rVar need 2+)")
    seed_start: int = Field(0, ge=0, le=1 << 20, description="number of the first seed: seeds "
                            "seed_start .. seed_start + K - 1 (nirc-bench ci adds seeds in groups)")
    eps: float = Field(0.01, gt=0.0, le=1.0, description="relative-error epsilon of MRSE")
    reference: ReferenceSpec = Field(default_factory=ReferenceSpec)
    keep_frames: bool = False
    time_budget: TimeBudget | None = Field(
        None, description="calibrate spp (pt) or N_c (nirc biased) to this frame time")
    denoised: bool = Field(
        DENOISED_DEFAULT, description="also score each seed's last frames after Intel Open "
                                      "Image Denoise (metrics.denoised: MRSE and FLIP of a "
                                      "frame and of four frames accumulated)")
    animation: Animation | None = Field(
        None, description="animate the (static) scene: camera keys, shape motions, emitter "
                          "changes (docs/animation.md); built-in animated scenes have theirs")

    _check_params = field_validator("params")(finite_params)

    @model_serializer(mode="wrap")
    def _stored_form(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        # Specs from before ``denoised`` and ``animation`` existed dump, store and hash as
        # they did: each is written only where it is not its default.
        data = handler(self)
        if data.get("denoised") == DENOISED_DEFAULT:
            data.pop("denoised")
        if data.get("animation", 0) is None:
            data.pop("animation")
        return data

    def versions(self) -> dict[str, int]:
        """The estimator version of the method and the metric version, as of today."""
        return versions_of(self.method)

    def key(self) -> str:
        """Content address of the spec under today's estimator and metric versions
        (equal specs give equal keys; a version bump gives new ones)."""
        data = self.model_dump(mode="json")
        if not data["seed_start"]:  # specs from before seed_start keep their keys
            del data["seed_start"]
        return digest("render-spec", keyed_budget(data), self.versions())


#: The methods a sweep can run (the registry's methods with a sweep role).
SWEEP_METHODS = sweep_methods()
#: Values a parameter sweep gives one parameter (each validated by the methods' models).
ParameterValue = bool | int | float | str


class ParameterSweep(BaseModel):
    """A sweep over one declared parameter of the sweep's methods: every value, for
    every method, is a render job (the sweep's seeds, frames and reference)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    name: str = Field(min_length=1, description="a parameter every method of the sweep "
                                                "declares, or a field inside a parameter "
                                                "that is a mapping, by a dotted path (e.g. "
                                                "'termination_params.threshold')")
    values: list[ParameterValue] = Field(min_length=1, max_length=1000,
                                         description="the values, in the order swept")

    @field_validator("values")
    @classmethod
    def _distinct(cls, values: list[ParameterValue]) -> list[ParameterValue]:
        if len({(type(v), v) for v in values}) != len(values):
            raise ValueError("the swept values must be distinct")
        return values


_MISSING = object()


def _nested(values: dict[str, Any], path: list[str]) -> Any:
    """The value at a dotted path of parameters, or _MISSING."""
    for key in path:
        if not isinstance(values, dict) or key not in values:
            return _MISSING
        values = values[key]
    return values


def _with_nested(values: dict[str, Any], path: list[str], value: Any) -> dict[str, Any]:
    """``values`` with the field at ``path`` set (the mappings on the way copied, kept
    fields kept): a dotted parameter sweep varies one field of a mapping parameter, e.g.
    a termination policy's own parameters."""
    if len(path) == 1:
        return {**values, path[0]: value}
    inner = values.get(path[0])
    inner = dict(inner) if isinstance(inner, dict) else {}
    return {**values, path[0]: _with_nested(inner, path[1:], value)}


def _knob_method(methods: list[str] | None = None) -> str:
    """The method an N_c sweep over ``methods`` and the equal-time series vary the knob
    of: the first of an equal-time pair of ``methods``, else the first sweep method
    that has an equal-time series."""
    pairs = equal_time_pairs(methods or [])
    return pairs[0][0] if pairs else next(
        name for name in SWEEP_METHODS if METHODS[name].sweep.equal_time_against is not None)


def _stored_termination() -> Any:
    """What sweep specs stored as their top-level ``termination`` while they had one: the
    knob method's default policy (read by the N_c sweep alone)."""
    return METHODS[_knob_method()].params.model_fields["termination"].default


def _nc_sweep_form(data: dict[str, Any]) -> dict[str, Any]:
    """A sweep given as an N_c sweep (``nc`` without eps and without a parameter; a
    top-level ``termination``), as the CLI, REST clients and stored specs give it: a
    parameter sweep over the knob of the knob method alone, the termination policy one
    of its parameters where it is not the default (docs/protocol.md)."""
    termination = data.pop("termination", None)
    nc_sweep = (data.get("nc") is not None and data.get("eps") is None
                and data.get("parameter") is None)
    if nc_sweep:
        methods = data.get("methods")
        method = _knob_method(methods if isinstance(methods, list) else None)
        values = data.pop("nc")
        if isinstance(values, str):
            values = parse_range(values, integer=True)
        if isinstance(values, list) and all(type(v) is int for v in values):
            values = sorted(set(values))
        data = {**data, "methods": [method],
                "parameter": {"name": METHODS[method].knob.name, "values": values}}
    if termination is None or termination == _stored_termination():
        return data
    if not nc_sweep:
        raise ValueError("termination at the top level is the N_c sweep's (nc without eps); "
                         "give a method's termination policy as params.termination")
    params = data.get("params")
    params = dict(params) if isinstance(params, dict) else {}
    if params.get("termination", termination) != termination:
        raise ValueError("termination is given twice (top level and params.termination) "
                         "with different policies")
    return {**data, "params": {**params, "termination": termination}}


class SweepSpec(BaseModel):
    """A sweep: the adaptive equal-bias protocol over eps (NIRC paper Sec. 6.3), or a
    sweep over any declared parameter of any method (``parameter``), of which the N_c
    sweep of biased NIRC is one (given by ``nc`` alone, :func:`_nc_sweep_form`).
    Expanded by ``jobs.sweeps.sweep`` into render jobs that share the reference (and,
    for the first, the trained caches)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    scene: str = Field(min_length=1, description=SCENE_DESCRIPTION)
    eps: list[float] | None = Field(
        None, description="relative-bias thresholds: use the cache at v1 where the per-pixel "
                          "relative bias of the converged cache-at-v1 image is below eps; a "
                          "list, or the CLI's text forms '0.05:1.0' (step = start), "
                          "'a:b:step', 'a,b,c'")
    nc: list[int] | None = Field(
        None, description="with eps: the N_c candidates of the 'NIRC equal time' series; "
                          "alone: an N_c sweep of biased NIRC (a parameter sweep over nc); "
                          "a list or text like '1:32' or '1,2,4'")
    parameter: ParameterSweep | None = Field(
        None, description="without eps and nc: the parameter and values of a parameter "
                          "sweep (a method's knob, NIRC's nc, is set as its equal-time "
                          "calibration sets it: N_c at the first vertex)")
    methods: list[str] = Field(default_factory=lambda: list(SWEEP_METHODS),
                               description="methods of the sweep: those with a sweep role for "
                                           "eps and N_c sweeps, any for a parameter sweep")
    resolution: int = Field(64, ge=1, le=8192, description="image width and height in pixels")
    seeds: int = Field(4, ge=2, le=1000, description="K independent caches and renders")
    frames: int = Field(1, ge=1, le=100_000, description="1-spp frames per sweep point")
    train_frames: int = Field(100, ge=1, le=100_000,
                              description="online-training frames of each cache")
    v1_spp: int = Field(256, ge=2, le=1 << 20,
                        description="spp of the converged cache-at-v1 image (rendered in passes "
                                    "for its variance, so at least 2)")
    bias_definition: Literal["relative-mse", "authors"] = Field(
        "relative-mse", description="per-pixel relative bias of the v1 mask (noise-corrected): "
                                    "'relative-mse' (root of the pixel's rBias2 term) or "
                                    "'authors' (per channel |V-R| / luminance(R), all pass)")
    max_depth: int = Field(DEFAULT_MAX_DEPTH, ge=-1, le=1024,
                           description="longest path in segments, renders, training paths and "
                                       "reference alike; -1 = unbounded (roulette ends paths)")
    equal_time: bool = Field(True, description="add the 'NIRC equal time' series (needs both "
                                               "methods)")
    probe_frames: int = Field(5, ge=1, le=1000, description="timed frames per calibration probe")
    time_tolerance_ms: float = Field(1.0, ge=0.0, le=1e6,
                                     description="equal time means within this many ms")
    calibration_rounds: int = Field(3, ge=1, le=100,
                                    description="interleaved timing rounds per calibration")
    time_max_spread: float = Field(0.1, gt=0.0, le=10.0,
                                   description="timing spread allowed before a calibration is "
                                               "flagged unstable, x the budget")
    allow_loaded: bool = Field(False, description="equal time: use calibration probes timed "
                                                  "on a loaded machine (default: left out "
                                                  "and taken again)")
    metric_eps: float = Field(0.01, gt=0.0, le=1.0, description="epsilon of MRSE / rBias2")
    params: dict[str, Any] = Field(default_factory=dict,
                                   description="extra parameters for every method")
    reference: ReferenceSpec = Field(default_factory=ReferenceSpec)
    denoised: bool = Field(DENOISED_DEFAULT, description="a parameter sweep's points also "
                                                         "scored after Intel Open Image "
                                                         "Denoise (RenderSpec.denoised)")

    _check_params = field_validator("params")(finite_params)

    @model_validator(mode="before")
    @classmethod
    def _nc_sweep(cls, data: Any) -> Any:
        return _nc_sweep_form(dict(data)) if isinstance(data, dict) else data

    @field_validator("eps", "nc", mode="before")
    @classmethod
    def _parse_ranges(cls, value: Any, info: ValidationInfo) -> Any:
        """The CLI's forms as well as a list: '0.05:1.0', 'a:b:step', 'a,b,c'
        (jobs.protocol.ranges.parse_range)."""
        if isinstance(value, str):
            return parse_range(value, integer=info.field_name == "nc")
        return value

    @field_validator("eps")
    @classmethod
    def _check_eps(cls, values: list[float] | None) -> list[float] | None:
        if values is None:
            return None
        if not values:
            raise ValueError("give at least one eps value")
        if any(not 0.0 < v <= 100.0 for v in values):
            raise ValueError("eps values must be in (0, 100]")
        return sorted(set(values))

    @field_validator("nc")
    @classmethod
    def _check_nc(cls, values: list[int] | None) -> list[int] | None:
        if values is None:
            return None
        if not values:
            raise ValueError("give at least one nc value")
        if any(not 1 <= v <= 256 for v in values):
            raise ValueError("nc values must be in 1..256")
        return sorted(set(values))

    @field_validator("methods")
    @classmethod
    def _check_methods(cls, values: list[str]) -> list[str]:
        if not values:
            raise ValueError("name at least one method")
        unknown = [name for name in values if name not in METHODS]
        if unknown:
            raise ValueError(f"unknown method(s) {', '.join(unknown)}; known: "
                             f"{', '.join(METHODS)}")
        return list(dict.fromkeys(values))

    @model_validator(mode="after")
    def _check_axes(self) -> SweepSpec:
        if self.eps is None and self.nc is None and self.parameter is None:
            raise ValueError("a sweep needs eps values (adaptive equal-bias), nc values or a "
                             "parameter")
        if self.parameter is not None:
            self._check_parameter(self.parameter)
        else:
            others = [name for name in self.methods if name not in SWEEP_METHODS]
            if others:
                raise ValueError(f"eps and N_c sweeps run {', '.join(SWEEP_METHODS)} (the "
                                 f"methods with a sweep role), not {', '.join(others)}")
        if self.denoised and self.parameter is None:
            raise ValueError("denoised scores a parameter sweep's points; eps and N_c "
                             "sweeps do not denoise")
        if "max_depth" in self.params:
            raise ValueError("set max_depth on the sweep, not in params")
        if self.max_depth == 0:
            raise ValueError("max_depth must be -1 (unbounded) or >= 1")
        return self

    @model_serializer(mode="wrap")
    def _stored_form(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        # Specs from before parameter sweeps dump, store and hash as they did, and so do
        # all but N_c sweeps from before the top-level termination was dropped: it held the
        # knob method's default wherever the N_c sweep's was not given; sweeps from before
        # ``denoised`` existed, as for render specs.
        data = handler(self)
        if data.get("parameter") is None:
            data.pop("parameter", None)
        if data.get("denoised") == DENOISED_DEFAULT:
            data.pop("denoised")
        if not self.is_nc_sweep:
            data["termination"] = _stored_termination()
        return data

    def _check_parameter(self, sweep: ParameterSweep) -> None:
        if self.eps is not None or self.nc is not None:
            raise ValueError("a parameter sweep takes neither eps nor nc values")
        path = sweep.name.split(".")
        if _nested(self.params, path) is not _MISSING or sweep.name == "max_depth":
            raise ValueError(f"{sweep.name} is swept: set it in parameter.values, not here")
        for method in self.methods:
            if path[0] not in METHODS[method].params.model_fields:
                raise ValueError(f"{method} has no parameter {path[0]!r}")
            for value in sweep.values:
                try:
                    self.parameter_point(method, value)
                except MethodError as err:
                    raise ValueError(f"{sweep.name}={value!r}: {err}") from None

    def parameter_point(self, method: str, value: ParameterValue) -> Any:
        """The validated parameters of ``method`` at one value of a parameter sweep: the
        sweep's parameters and depth, the value (a knob's by the knob), and
        ``train_frames`` pre-training frames where the method trains a cache."""
        assert self.parameter is not None
        shared = {**self.params, "max_depth": self.max_depth}
        knob = METHODS[method].knob
        if knob is not None and knob.apply is not None and knob.name == self.parameter.name:
            # Set as the equal-time calibration sets the knob (NIRC: N_c at v1).
            if not knob.usable(shared):
                raise MethodError(f"{method}'s {knob.name} is swept as its knob, which needs "
                                  f"{knob.requirement}")
            values = knob.apply(shared, value)  # type: ignore[arg-type]
        else:
            values = _with_nested(shared, self.parameter.name.split("."), value)
        if "pretrain_frames" in METHODS[method].params.model_fields:
            values.setdefault("pretrain_frames", self.train_frames)
        return parse_params(method, values)

    @property
    def kind(self) -> str:
        return "parameter" if self.parameter is not None else "eps"

    @property
    def is_nc_sweep(self) -> bool:
        """A sweep over the knob of the knob method alone (the N_c sweep)."""
        method = _knob_method()
        return (self.parameter is not None and self.methods == [method]
                and self.parameter.name == METHODS[method].knob.name)

    @property
    def knob_method(self) -> str:
        """The method whose knob the equal-time series calibrates."""
        return _knob_method(self.methods)

    def nc_candidates(self) -> list[int]:
        knob = METHODS[self.knob_method].knob
        return self.nc if self.nc is not None else list(knob.candidates if knob else ())

    def base_render_spec(self) -> RenderSpec:
        """The render job every point of the sweep specialises (scene, reference, depth)."""
        return RenderSpec(scene=self.scene, method=BASELINE, params={"max_depth": self.max_depth},
                          resolution=self.resolution, spp=1, frames=self.frames,
                          seeds=self.seeds, eps=self.metric_eps, reference=self.reference,
                          denoised=self.denoised)

    def versions(self) -> dict[str, object]:
        """The estimator versions of the sweep's methods and the metric version."""
        return {"estimator_versions": sweep_estimator_versions(self.methods),
                "metric_version": METRIC_VERSION}

    def key(self, device_key: str) -> str:
        """Content address of the sweep on one device (timings are per device) under
        today's versions."""
        return digest("sweep-spec", keyed_budget(self.model_dump(mode="json")), device_key,
                      self.versions())
